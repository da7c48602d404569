"""The live monitor on ROS 2 (``spaceid ros monitor``): the input rate it keeps up with, and the
time from the message that reveals a change to the published alarm.

The ideal Cepheus twin (cepheus-rw, wheel at 170 rad/s) grasps 0.5 kg 4 s into a ``--duration``
s run of paper-table2: encoders at 50 Hz, motion capture at 100 Hz. The monitor's settings are
those of tests/test_ros.py (rates differentiated over 25 samples, 100-sample warm-ups, noise
levels given).

(a) capacity, no middleware: the run's messages (rclpy message objects, built beforehand) fed
    to :class:`spaceid.ros.LiveMonitor` one by one, as fast as it takes them (parts of
    ``--block`` s), ``--repeats`` times: joint-state samples per second of wall time and of this
    process's processor time (alignment, differentiation, the monitor, the alarms, the events,
    the estimate after each part and the payload after each alarm included), median and range;
    then a steady run without a change (``--steady-samples`` at 100 Hz on Cepheus, the sine motion
    of bench_monitor.py; one warm-up, then only the test): where the per-sample costs dominate;
    then queue runs: the messages arriving at each ``--queue`` factor times real time (10: 500
    joint samples/s) and taken in batches of all that have arrived, as the node takes them
    (:meth:`~spaceid.ros.LiveMonitor.add_batch`): how long after its arrival the last message
    was processed (kept up: about one part's processing), the longest wait in the queue, and the
    alarms' ``latency_s``; then the queue runs again on a clock of this process's processor time
    (the waits for the next message added to it): the figures on a core of its own, whatever
    the machine's load. Each run starts without the differentiator's fits that an earlier run in
    this process remembered (a node remembers only those of its own records before);
(b) over DDS on the loopback (localhost discovery, a domain of its own): ``spaceid ros play`` of
    the run's bag at ``--rate-factor`` times real time (50 x F joint samples/s in, plus 100 x F
    poses/s), the monitor in its own process, this process subscribed to its topics and to the
    joint states: each estimate's publication after the arrival here of its last sample's joint
    state and, per alarm and event, ``latency_s`` (from the arrival of the message that completed
    the revealing sample, half a differentiator window after it, at the monitor's middleware, to
    the publication; for "undetermined", of the warm-up's last sample) and the
    time from the revealing sample's own joint state to the message's arrival here, with the
    event's time on the data clock after the grasp. The data's own waits: the revealing sample's
    rate needs half a differentiator window (0.25 s of data), its part up to ``--block`` s more;
    the event's comparison needs the warm-up after the alarm.

Prints only; never fails on the figures.

    python benchmarks/bench_ros.py [--duration 12] [--repeats 3] [--rate-factor 1] [--steady-samples 6000]
        [--queue 1 10] [--block 0.1] [--estimator ml] [--parts a b]
"""

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from spaceid import load_model, minimal_parameters
from spaceid.estimation import Noise
from spaceid.ros import LIVE_BLOCK, LiveMonitor, twin_recording
from spaceid.studies import capture_protocol

ROTOR = 0.00197372
NOISE = Noise(angle=1e-3, rate=1e-2, base_rate=1e-2)


def _run(duration, capture=True):
    run = twin_recording(capture=capture_protocol() if capture else None, ideal=True, duration=duration, seed=1)
    return run, run.meta["capture"]["time"] if capture else None


ESTIMATOR = "ml"
BLOCK = LIVE_BLOCK


def _forget_fits():
    """Forget the Savitzky-Golay fits remembered in this process (each row's by its stamps): a
    repeat of the same run would find every window's fit from the run before, where a node finds
    only those of the records before in the same run. Each run starts as a node does."""
    from spaceid.data import _signal_savgol

    _signal_savgol._ROW_FITS.clear()
    _signal_savgol._remembered_fits.cache_clear()


def _live(**options):
    _forget_fits()
    param = minimal_parameters(load_model("cepheus-rw"))
    return LiveMonitor(param, np.zeros(3), link="link2", reading={"window": 25}, known={"Iczz_wheel": ROTOR},
                       warmup=100, noise=NOISE, estimator=ESTIMATOR, block=BLOCK, **options)


def capacity(run, grasp, repeats, label):
    """Joint samples per second of wall time that LiveMonitor takes the run's messages at."""
    from geometry_msgs.msg import PoseStamped
    from sensor_msgs.msg import JointState

    from spaceid.ros._node import _messages

    messages = list(_messages(run.recording, 0, JointState, PoseStamped))
    rates, cpus, payloads = [], [], 0
    for _ in range(repeats + 1):  # the first warms the compiled kernels up: not counted
        live = _live()
        topics = (live.aligner.joint_topic, live.aligner.pose_topic)
        start, cpu = time.perf_counter(), time.process_time()
        for _, is_joint, msg in messages:
            live.add(topics[0] if is_joint else topics[1], msg)
            payloads += live.payload() is not None
        _, record = live.finish()
        rates.append(record.n_samples / (time.perf_counter() - start))
        cpus.append(record.n_samples / (time.process_time() - cpu))
    rates, cpus = rates[1:], cpus[1:]
    origin = live._origin / 1e9
    events = ", ".join(f"{e.time + origin - grasp:+.2f}" for e in record.events) if grasp is not None else \
        str(len(record.events))
    print(f"(a) {label}: {record.n_samples} joint samples, {len(messages)} messages: {statistics.median(rates):.0f} "
          f"samples/s (range {min(rates):.0f}..{max(rates):.0f}, {repeats} runs; of CPU time "
          f"{statistics.median(cpus):.0f}); events "
          f"{events}{' s from the grasp' if grasp is not None else ''}; {len(record.segments)} segments identified")


def queue(run, grasp, factor, repeats, cpu=False):
    """LiveMonitor fed as the node feeds it, without the middleware: the run's messages arrive at
    ``factor`` times real time (each at its stamp's offset over ``factor`` after the start) and each
    call takes all that have arrived (:meth:`~spaceid.ros.LiveMonitor.add_batch`, then the payload
    check). Kept up when the last message is processed shortly after it arrives; the alarm's
    latency from the arrival of the message that completed its revealing sample. With ``cpu``, on
    a clock of this process's processor time (the waits for the next message added to it): the
    figures on a core of its own, whatever the machine's load."""
    from geometry_msgs.msg import PoseStamped
    from sensor_msgs.msg import JointState

    from spaceid.ros._node import _messages

    messages = list(_messages(run.recording, 0, JointState, PoseStamped))
    t0 = messages[0][0]
    lags, latencies, behind = [], [], []
    idle = [0.0]  # the processor-time clock's waits
    clock = (lambda: time.process_time() + idle[0]) if cpu else time.monotonic
    for _ in range(repeats + 1):  # the first warms the compiled kernels up: not counted
        live = _live(clock=clock)
        topics = (live.aligner.joint_topic, live.aligner.pose_topic)
        alarms, most = [], 0.0
        start, k = clock(), 0
        while k < len(messages):
            now = clock()
            due = start + (messages[k][0] - t0) / factor
            if due > now:
                if cpu:
                    idle[0] += due - now
                else:
                    time.sleep(due - now)
                continue
            j = k
            while j < len(messages) and start + (messages[j][0] - t0) / factor <= now:
                j += 1
            batch = [(topics[0] if m[1] else topics[1], m[2], start + (m[0] - t0) / factor) for m in messages[k:j]]
            most = max(most, now - batch[0][2])  # the oldest message's wait in the queue
            k = j
            out = live.add_batch(batch)
            alarms += [o.data for o in out if o.kind == "event" and o.data["stage"] == "detected"]
            live.payload()
        lags.append(clock() - (start + (messages[-1][0] - t0) / factor))
        behind.append(most)
        latencies.append([a["latency_s"] for a in alarms])
        live.finish()
    lags, behind, latencies = lags[1:], behind[1:], [x for one in latencies[1:] for x in one]
    n = run.recording.joints.t.size
    rate = n / (run.recording.joints.t[-1] - run.recording.joints.t[0]) * factor
    lat = (f"alarm latency median {1000 * statistics.median(latencies):.0f} ms (range {1000 * min(latencies):.0f}.."
           f"{1000 * max(latencies):.0f}, {len(latencies)} alarms)") if latencies else "no alarm"
    print(f"(a) queue at {factor:g}x real time{', processor-time clock' if cpu else ''}, {rate:.0f} joint samples/s "
          f"in: the last message processed {statistics.median(lags):.2f} s after its arrival (range "
          f"{min(lags):.2f}..{max(lags):.2f}, {repeats} runs); longest wait in the queue {max(behind):.2f} s; {lat}")


def steady(n, repeats):
    """Joint samples per second that LiveMonitor takes a long run without a change at: Cepheus at
    100 Hz, the two-joint sine motion of bench_monitor.py (h = 0.5 N m s, 1e-4 rad on the angles
    and the attitude), published as joint states and poses, the rates differentiated over 31
    samples; one warm-up, then the test phase (false-alarm rate 1e-9)."""
    from geometry_msgs.msg import PoseStamped
    from sensor_msgs.msg import JointState

    from spaceid.motion import add_noise, simulate
    from spaceid.ros import recording_of_log
    from spaceid.ros._node import _messages

    model = load_model("cepheus")
    param = minimal_parameters(model)
    h = np.array([0.0, 0.0, 0.5])

    def motion(t):
        arg = 2 * np.pi * np.array([0.3, 0.45]) * np.asarray(t)[:, None] + np.array([0.0, 1.0])
        return 0.5 * np.sin(arg), 0.5 * 2 * np.pi * np.array([0.3, 0.45]) * np.cos(arg)

    log = add_noise(simulate(param, param.true_values, motion, np.arange(n) / 100.0, h, model=model), angle=1e-4,
                    rate=1e-3, seed=0)
    messages = list(_messages(recording_of_log(log), 0, JointState, PoseStamped))
    rates, cpus = [], []
    for _ in range(repeats + 1):
        _forget_fits()
        live = LiveMonitor(param, h, reading={"window": 31}, noise=Noise(angle=1e-4, rate=1e-3, attitude=1e-4,
                                                                          base_rate=1e-3),
                           false_alarm_rate=1e-9, estimator=ESTIMATOR, block=BLOCK)
        topics = (live.aligner.joint_topic, live.aligner.pose_topic)
        start, cpu = time.perf_counter(), time.process_time()
        for _, is_joint, msg in messages:
            live.add(topics[0] if is_joint else topics[1], msg)
        _, record = live.finish()
        rates.append(record.n_samples / (time.perf_counter() - start))
        cpus.append(record.n_samples / (time.process_time() - cpu))
    rates, cpus = rates[1:], cpus[1:]
    print(f"(a) steady, Cepheus at 100 Hz without a change: {record.n_samples} joint samples, {len(record.events)} "
          f"events: {statistics.median(rates):.0f} samples/s (range {min(rates):.0f}..{max(rates):.0f}, "
          f"{repeats} runs; of CPU time {statistics.median(cpus):.0f})")


def over_dds(run, grasp, rate_factor, block):
    import rclpy
    from rclpy.context import Context
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String

    from spaceid.data import write_bag
    from spaceid.ros._node import _take_all

    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(1 + os.getpid() % 100))
    folder = Path(tempfile.mkdtemp(prefix="bench_ros_"))
    write_bag(folder / "run.mcap", run.recording, format="mcap")
    context = Context()
    rclpy.init(context=context, domain_id=int(env["ROS_DOMAIN_ID"]))
    node = rclpy.create_node("bench_listener", context=context)
    got = {"estimate": [], "events": []}
    subs = []  # taken as the node takes them, with the middleware's reception times: at 10x an executor's round
    for name in got:  # per message let this listener fall seconds behind, and its callbacks' clocks with it
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL if name == "events" else DurabilityPolicy.VOLATILE)
        subs.append((node.create_subscription(String, f"/spaceid/{name}", lambda m: None, qos), name, None))
    reliable = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    subs.append((node.create_subscription(JointState, "/joint_states", lambda m: None, reliable), "joints", None))
    joints = []  # (stamp [ns], arrival here): when each joint state reached this process

    def take():
        time.sleep(0.002)
        for topic, msg, arrival in _take_all(subs):
            if topic == "joints":
                joints.append((msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec, arrival))
            else:
                got[topic].append((arrival, json.loads(msg.data)))
    cli = [sys.executable, "-m", "spaceid.cli", "ros"]
    logs = [open(folder / f"{name}.log", "w") for name in ("monitor", "play")]  # noqa: SIM115  (pipes could fill)
    monitor = subprocess.Popen(cli + ["monitor", "cepheus-rw", "--momentum", "0", "--known", f"Iczz_wheel={ROTOR}",
                                      "--warmup", "100", "--noise-angle", "1e-3", "--noise-rate", "1e-2",
                                      "--noise-base-rate", "1e-2", "--window", "25", "--link", "link2",
                                      "--block", str(block), "--estimator", ESTIMATOR,
                                      "-o", str(folder / "events.json")],
                               env=env, stdout=logs[0], stderr=subprocess.STDOUT, text=True)
    ready = time.monotonic() + 60  # this listener matched to the monitor's publishers before the play starts:
    while time.monotonic() < ready and not all(node.count_publishers(f"/spaceid/{name}") for name in got):
        take()  # at 10x the whole run lasts 1.2 s, and a late match delivered the events seconds after
    play = subprocess.Popen(cli + ["play", str(folder / "run.mcap"), "--rate-factor", str(rate_factor)], env=env,
                            stdout=logs[1], stderr=subprocess.STDOUT, text=True)
    deadline = time.monotonic() + 600
    try:
        while play.poll() is None and time.monotonic() < deadline:
            take()
        ended = time.monotonic()
        settle = ended + max(5.0, 2 * block / rate_factor + 2.0)
        while time.monotonic() < settle:
            take()
        monitor.send_signal(signal.SIGINT)
        while monitor.poll() is None and time.monotonic() < deadline:  # the rest is published at the interrupt
            take()
        take()
    finally:
        for p in (monitor, play):
            if p.poll() is None:
                print(f"killed {p.args[4]} at the deadline")
                p.kill()
            p.wait()
        for f in logs:
            f.close()
    if monitor.returncode != 0:
        last = (folder / "monitor.log").read_text().strip().splitlines()[-1:]
        print(f"monitor exit code {monitor.returncode}: {last}")
    node.destroy_node()
    context.try_shutdown()
    n = run.recording.joints.t.size
    arrival = dict(joints)
    stamps = np.array(sorted(arrival))
    lags = []  # each estimate's publication after the arrival here of its last sample's joint state
    for t, d in got["estimate"]:
        k = np.searchsorted(stamps, d["time_origin_ns"] + round(d["time"] * 1e9))
        if k < stamps.size:
            lags.append(t - arrival[stamps[k]])
    print(f"(b) {rate_factor:g}x real time: {50 * rate_factor:.0f} joint samples/s in ({n} in {play.returncode=}), "
          f"block {block:g} s; {len(got['estimate'])} estimates published ("
          f"{sum(d.get('status') == 'testing' for _, d in got['estimate'])} of them testing), each after the arrival "
          f"of its last "
          f"sample's joint state (which waits half a differentiator window, 0.25 s of data, for its rate): "
          + (f"median {statistics.median(lags):.3f} s, max {max(lags):.3f} s" if lags else "none"))
    for t, e in got["events"]:
        origin = e["time_origin_ns"] / 1e9
        k = np.searchsorted(stamps, e["time_origin_ns"] + round(e["detected_at"] * 1e9))
        seen = f"{t - arrival[stamps[k]]:.3f} s" if k < stamps.size else "?"
        print(f"    event {e['index']} {e['stage']}: at {e['time'] + origin - grasp:+.3f} s from the grasp (data "
              f"clock; detected at {e['detected_at'] + origin - grasp:+.3f} s); published "
              f"{1000 * e['latency_s']:.1f} ms "
              f"after the arrival of the message that completed the revealing sample (the monitor's latency_s); "
              f"received here {seen} after the revealing sample's own joint state")
    lat = [e["latency_s"] for _, e in got["events"] if e["stage"] == "detected"]
    if lat:
        print(f"    alarm latency median {1000 * statistics.median(lat):.1f} ms, max {1000 * max(lat):.1f} ms "
              f"({len(lat)} alarms)")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=12.0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--rate-factor", type=float, default=1.0)
    ap.add_argument("--block", type=float, default=LIVE_BLOCK, help="seconds of joint states aligned at a time")
    ap.add_argument("--parts", nargs="+", default=["a", "b"])
    ap.add_argument("--steady-samples", type=int, default=6000)
    ap.add_argument("--queue", type=float, nargs="*", default=[1.0, 10.0],
                    help="speed-ups over real time of the queue runs (10: 500 joint samples/s)")
    ap.add_argument("--estimator", default="ml", help="of the monitor's batch identifications")
    args = ap.parse_args()
    global ESTIMATOR, BLOCK
    ESTIMATOR, BLOCK = args.estimator, args.block
    run, grasp = _run(args.duration)
    if "a" in args.parts:
        quiet, _ = _run(args.duration, capture=False)
        capacity(quiet, None, args.repeats, "no change")
        capacity(run, grasp, args.repeats, "grasp 4 s in")
        steady(args.steady_samples, args.repeats)
        for factor in args.queue:
            queue(run, grasp, factor, args.repeats)
        for factor in args.queue:
            queue(run, grasp, factor, args.repeats, cpu=True)
    if "b" in args.parts:
        over_dds(run, grasp, args.rate_factor, args.block)


if __name__ == "__main__":
    main()
