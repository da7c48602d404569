"""
A lab recording: identification from a ROS bag
==============================================

On the table, the arm's encoders publish ``sensor_msgs/JointState`` on ``/joint_states`` and the
motion-capture system publishes the base pose as ``geometry_msgs/PoseStamped``; ``rosbag
record`` (or ``ros2 bag record``) stores both. spaceid reads ROS 1 bags, ROS 2 bag folders and
MCAP files directly (no ROS installation), aligns the two streams on one time base,
differentiates the base attitude into the base angular velocity and identifies.

This tutorial makes such a bag itself, with the names a lab would have (joints ``shoulder``
and ``elbow``, the pose on ``/mocap/cepheus/pose``), writes a mapping file that translates them
to the model's names (:doc:`/formats/bag-mapping`), identifies from the bag and validates on a
second recording of a different motion. From a shell:

.. code-block:: bash

    spaceid identify cepheus run.bag --momentum 0.4934 --mapping mapping.yaml -o result.json
    spaceid validate result.json second.bag --momentum 0.4934 --mapping mapping.yaml --out validation/
"""

# %%
# Recording a run
# ---------------
# The motion is the paper's exciting trajectory on ``cepheus``, simulated at 100 Hz with white
# noise of 1e-4 rad on the angles and 1e-4 rad/s on the joint rates. Joint states go out at
# 50 Hz (every second sample), the motion-capture pose at 100 Hz. Only the attitude of the
# pose matters to the method; the position is recorded as zero here.

import shutil
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

import spaceid
from spaceid.data import JointStates, Poses, Recording, write_bag

model = spaceid.load_model("cepheus")
param = spaceid.minimal_parameters(model)
h = np.array([0.0, 0.0, 0.4934])
times = np.arange(0.0, 5.0 + 1e-9, 0.01)  # 100 Hz
folder = Path(tempfile.mkdtemp(prefix="spaceid-tutorial-"))


def record(traj, bag, seed):
    """Simulate ``traj`` with noise and write it as a lab would record it; return the true motion."""
    truth = spaceid.simulate(param, param.true_values, traj, times, h, model=model)
    measured = spaceid.add_noise(truth, angle=1e-4, rate=1e-4, seed=seed)
    joints = JointStates(t=measured.t[::2], names=("shoulder", "elbow"), position=measured.q[::2],
                         velocity=measured.qd[::2])
    poses = Poses(t=measured.t, position=np.zeros((measured.n_samples, 3)), quat=measured.base_quat, frame="world")
    write_bag(bag, Recording(joints=joints, base=poses), pose_topic="/mocap/cepheus/pose",
              time_origin_ns=1_700_000_000 * 10**9)  # wall-clock stamps, as a real recording has
    print(f"{bag.name}: {bag.stat().st_size} bytes; {joints.t.size} joint states, {poses.t.size} poses")
    return truth, joints


bag = folder / "run.bag"
truth, joints = record(spaceid.load_trajectory("paper-table2", joints=model.joints), bag, seed=3)
assert bag.is_file()

# %%
# The mapping file
# ----------------
# The bag's joint names and pose topic are not the model's: a small YAML file says how they
# correspond (bag name on the left, model name on the right), and may set how the streams are
# aligned. Every key is optional.

mapping = folder / "mapping.yaml"
mapping.write_text(
    "joint_topic: /joint_states\n"
    "pose_topic: /mocap/cepheus/pose\n"
    "joints: {shoulder: left_shoulder, elbow: left_elbow}   # bag name: model name\n"
    "pose_latency: 0.0   # s: the pose stamped t was captured at t - latency\n"
    "max_gap: 0.1        # s: longest gap without messages that is bridged\n"
)
print(spaceid.data.read_mapping(mapping))

# %%
# Reading the bag
# ---------------
# ``read_log`` recognises the bag by its suffix. The time base is the joint-state stamps; the
# joint rates and the base angular velocity are differentiated from the angles and the attitude
# (a smoothing differentiator with its window chosen from the data), which the log's ``meta``
# records. The messages' velocities are not used by default: encoder drivers often publish
# one-tick differences, far noisier (``joint_rates="auto"``, ``--joint-rates auto``, uses them).

log = spaceid.read_log(bag, joints=model.joints, planar=True, bag_options={"mapping": mapping})
print(f"{log.n_samples} samples from t = {log.t[0]:.3f} s to {log.t[-1]:.3f} s; joint rates: {log.meta['joint_rates']}")
print("base rate:", log.meta["differentiation"]["base"])
assert log.n_samples == joints.t.size and log.joints == model.joints

# %%
# The recording carries wall-clock stamps; the log's time counts from the whole second at or
# before the first stamp, here the start of the run. The differentiated base rate follows the
# true one closely:

true_wz = np.interp(log.t, truth.t, truth.base_w[:, 2])
print(f"base rate error: RMS {np.sqrt(np.mean((log.base_w[:, 2] - true_wz) ** 2)):.2g} rad/s")

fig, ax = plt.subplots(figsize=(6.4, 3.0), layout="constrained")
ax.plot(log.t, log.base_w[:, 2] - true_wz, color="0.2")
ax.set_xlabel("t [s]")
ax.set_ylabel("error [rad/s]")
ax.set_title("Base angular velocity differentiated from the poses, minus the truth")

# %%
# Identifying
# -----------
# The log from the bag identifies like any other. Its rates came from a differentiator, whose
# errors are correlated over its window; the standard errors are then the angle noise propagated
# through the differentiator, or the Newey-West estimate from the residuals where that is larger
# (:doc:`/theory/noise`), as ``diagnostics.covariance`` says.

result = spaceid.identify(param, log, h)
rel = (result.values - param.true_values) / param.true_values
for name, err, std in zip(result.names, rel, result.std / abs(param.true_values)):
    print(f"{name}: error {100 * err:+.3f} %  (std {100 * std:.3f} %)")
print("covariance:", result.diagnostics.covariance)
assert np.all(abs(rel) < 0.03)
assert np.all(abs(result.values - param.true_values) < 5 * result.std)

# %%
# Validating
# ----------
# Re-simulated on the log it was fitted to, any fit looks good (``validate`` warns when given
# it). A second recording of a different motion, here a designed trajectory, tests the model;
# ``validate`` reads that bag the same way (``spaceid validate ... --mapping mapping.yaml``):

second = spaceid.design_excitation(param, duration=5.0, harmonics=3, samples=35, momentum=h, seed=1,
                                   n_starts=4).trajectory
record(second, folder / "second.bag", seed=4)
held_out = spaceid.read_log(folder / "second.bag", joints=model.joints, planar=True, bag_options={"mapping": mapping})
metrics = spaceid.validate(result, held_out, momentum=h).metrics
print(f"base rate RMS error of the identified model on the second motion: {metrics['base_w_rms']:.2g} rad/s "
      f"({100 * metrics['base_w_nrms']:.2g} % of its RMS)")
assert metrics["base_w_nrms"] < 0.01

# %%
# The files of this tutorial went into a temporary folder; remove it.

shutil.rmtree(folder)
