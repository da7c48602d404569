"""
Live on ROS 2: a grasp detected as the messages arrive
======================================================

During a servicing rehearsal the lab wants to see the capture detected and the payload it
holds identified while the robot runs, on the topics it already has (:doc:`/live`). Here the
Cepheus digital twin grasps 0.5 kg 4 s into a 12 s motion; its encoders and motion capture are
recorded as an MCAP bag, which ``spaceid ros play`` publishes over DDS on this machine's
loopback (a process of its own), and the live monitor, :class:`spaceid.ros.LiveMonitor` run by
:func:`spaceid.ros.run_monitor`, subscribes to them in this process. From a shell the same
loop is:

.. code-block:: bash

    export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST ROS_DOMAIN_ID=42
    spaceid ros monitor cepheus-rw --momentum 0 --known Iczz_wheel=0.00197372 --warmup 100 \\
        --noise-angle 1e-3 --noise-rate 1e-2 --noise-base-rate 1e-2 --window 25 --link link2 -o events.json &
    spaceid ros play run.mcap --rate-factor 2
"""

# %%
# The recording
# -------------
# :func:`spaceid.ros.twin_recording` runs the ideal twin (friction and thrusters off) with the
# grasp, and returns what its sensors publish: joint states at 50 Hz, base poses at 100 Hz,
# stamped on the twin's clock.

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

import spaceid
from spaceid.data import write_bag
from spaceid.estimation import Noise
from spaceid.ros import LiveMonitor, run_monitor, twin_recording
from spaceid.studies import capture_protocol

run = twin_recording(capture=capture_protocol(), ideal=True, duration=12.0, seed=1)
grasp = run.meta["capture"]["time"]
folder = Path(tempfile.mkdtemp(prefix="spaceid-live-"))
bag = folder / "run.mcap"
write_bag(bag, run.recording, format="mcap")
print(f"grasp at {grasp:.2f} s; {run.recording.joints.t.size} joint states, {run.recording.base.t.size} poses")

# %%
# The monitor and the player
# --------------------------
# Discovery is kept on this machine and the ROS domain is one of this build's own, so that
# nothing else on the network hears the loop. The monitor is built as ``spaceid ros monitor``
# builds it: the wheel's rotor inertia anchors the scale at zero momentum, the rates are
# differentiated over 25 samples, each segment's warm-up is 100 samples, and ``link2`` is the
# link that grasps. The player waits for the monitor's subscriptions, then publishes at twice
# real time; the monitor runs until the player has ended and its last messages are in (every
# wait bounded: a broken loop fails the docs build instead of hanging it).

os.environ.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(101 - os.getpid() % 50))
param = spaceid.minimal_parameters(spaceid.load_model("cepheus-rw"))
live = LiveMonitor(param, np.zeros(3), link="link2", reading={"window": 25}, known={"Iczz_wheel": 0.00197372},
                   warmup=100, noise=Noise(angle=1e-3, rate=1e-2, base_rate=1e-2))

player = subprocess.Popen([sys.executable, "-m", "spaceid.cli", "ros", "play", str(bag), "--rate-factor", "2"],
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
seen, started, ended = [], time.monotonic(), None


def done():
    """The player ended 5 s ago (its last messages are in), or 120 s have passed."""
    global ended
    if ended is None and player.poll() is not None:
        ended = time.monotonic()
    return (ended is not None and time.monotonic() > ended + 5.0) or time.monotonic() > started + 120.0


try:
    _, record = run_monitor(live, on_output=lambda out: seen.append((time.monotonic() - started, out)), until=done)
finally:
    if player.poll() is None:
        player.kill()
    _, err = player.communicate(timeout=30)
assert player.returncode == 0, err
print(f"{record.n_samples} samples monitored in {time.monotonic() - started:.1f} s; {len(record.events)} change(s)")

# %%
# What was published
# ------------------
# On ``/spaceid/events`` each change comes first as the alarm the moment the test raises it
# (``stage`` "detected": the estimated change time, the sample that crossed the threshold, with
# ``latency_s`` from the arrival of the message that completed that sample), and last as
# its comparison once the segment after it has a warm-up identified (``stage`` "compared":
# which parameters changed, with their z-scores). In between, while the samples after the
# change do not determine the estimate (here they never do: after the grasp the arm barely moves
# some directions of the parameters, and the comparison completes at the end), ``stage``
# "undetermined" says which parameters they leave undetermined, and how those they determine
# changed, a warm-up after the alarm and each time the samples double. On ``/spaceid/payload``,
# the payload that ``link2`` holds, identified from the samples after the alarm (the servicer
# known: far fewer unknowns), first once its mass stands out of its standard error (tried each
# quarter warm-up of samples), and again each time they double. ``/spaceid/estimate`` comes after every aligned part: the
# running segment's recursive estimate while its test runs (``status`` "testing"), else its
# warm-up's last identification with the parameters not yet determined (``status`` "warming
# up"; here the first warm-up is determined only after 3.5 s, and the change is found in its
# own test: :doc:`/theory/monitor`).

origin, status = None, None
for wall, out in seen:
    d = out.data
    if out.kind == "event":
        origin = d["time_origin_ns"] / 1e9
        if d["stage"] == "undetermined":
            print(f"[{wall:5.1f} s] change {d['index']} undetermined: the {d['warm_up']['n_samples']} samples after "
                  f"it do not determine {', '.join(d['warm_up']['undetermined'])}")
            continue
        print(f"[{wall:5.1f} s] change {d['index']} {d['stage']}: at {d['time'] + origin:.2f} s "
              f"(grasp {grasp:.2f} s; detected at {d['detected_at'] + origin:.2f} s), published "
              f"{1000 * d['latency_s']:.0f} ms after the message that completed the revealing sample")
    elif out.kind == "estimate" and d["status"] != status:
        status = d["status"]
        print(f"[{wall:5.1f} s] estimate of segment {d['segment']}: {status}")
    elif out.kind == "payload" and "mass" in d:
        print(f"[{wall:5.1f} s] payload after change {d['event']}: {d['mass']:.3f} +/- {d['std']['mass']:.3f} kg "
              f"from {d['n_samples']} samples")
detected = [out.data for _, out in seen if out.kind == "event" and out.data["stage"] == "detected"]
assert any(abs(e["time"] + origin - grasp) <= 0.5 for e in detected), "the grasp was not detected"

# %%
# The payload converging
# ----------------------
# Each payload message is a new identification from all the samples after the change so far:
# the mass settles on the true 0.5 kg, its standard error shrinking as the samples double.

payloads = [out.data for _, out in seen if out.kind == "payload" and "mass" in out.data]
assert payloads and all(abs(p["mass"] - 0.5) <= 2 * p["std"]["mass"] for p in payloads), payloads
n = np.array([p["n_samples"] for p in payloads])
mass = np.array([p["mass"] for p in payloads])
std = np.array([p["std"]["mass"] for p in payloads])
fig, (ax, bx) = plt.subplots(1, 2, figsize=(9, 3.2), layout="constrained")
ax.errorbar(n, mass, yerr=2 * std, fmt="o", capsize=3, label="published (2 sigma)")
ax.axhline(0.5, color="k", lw=0.8, ls="--", label="true 0.5 kg")
ax.set(xlabel="samples after the change", ylabel="payload mass [kg]", xscale="log")
ax.legend()
js = run.recording.joints
arm = [k for k, name in enumerate(js.names) if "wheel" not in name]  # the wheel spins at 170 rad/s throughout
for k in arm:
    bx.plot(js.t, js.position[:, k], lw=0.8, label=js.names[k])
bx.axvline(grasp, color="k", ls="--", lw=0.8, label="grasp")
for e in detected:
    bx.axvline(e["detected_at"] + origin, color="C3", lw=1.2, label="alarm (its revealing sample)")
bx.set(xlabel="twin clock [s]", ylabel="joint angles [rad]")
bx.legend(loc="best", fontsize="small")
plt.show()

# %%
# The estimate after each part
# ----------------------------
# ``/spaceid/estimate`` came after every aligned part. Here one parameter with its 2-sigma band:
# while a warm-up waits (grey) the values are its last identification's, whose standard errors do
# not cover the bias of the parameters it names undetermined; once its samples determine the
# estimate (segment 0 from 3.5 s of motion), the recursive estimate of the test phase (blue).
# After the grasp the segment's warm-up never is determined: its estimates stay grey.

estimates = [out.data for _, out in seen if out.kind == "estimate" and out.data["values"] is not None]
k = estimates[0]["names"].index("pi5")
fig, ax = plt.subplots(figsize=(6, 3), layout="constrained")
for status, color in (("warming up", "0.5"), ("testing", "C0")):
    shown = [e for e in estimates if e["status"] == status]
    t = np.array([e["time"] + e["time_origin_ns"] / 1e9 for e in shown])
    v, s = np.array([e["values"][k] for e in shown]), np.array([e["std"][k] for e in shown])
    ax.errorbar(t, v, yerr=2 * s, fmt=".", color=color, capsize=2, label=f"{status} ({len(shown)} messages)")
ax.axvline(grasp, color="k", ls="--", lw=0.8, label="grasp")
ax.set(xlabel="twin clock [s]", ylabel="pi5", title="/spaceid/estimate, pi5 +/- 2 sigma")
ax.legend(fontsize="small")
plt.show()
