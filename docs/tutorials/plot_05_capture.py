"""
Before and after a capture: what changed
========================================

On-orbit servicing changes a robot's dynamics: a servicer that grasps a defunct satellite
carries its mass and inertia from then on. The kinematic structure is the same, so the same
minimal parameter set describes the system before and after; identifying it twice, from the
same kind of motion, and comparing the two results shows which parameter combinations the
capture changed, and by how much beyond the estimation noise.

The example is ``servicer-dual``, a 14-joint dual-arm servicer (496 minimal parameters), and
``servicer-captured``, the same servicer holding a 150 kg target rigidly in its left end
effector (the target merged into ``left_link7``). From a shell, with two logs recorded before
and after:

.. code-block:: bash

    NOISE="--noise-angle 1e-5 --noise-rate 1e-5 --noise-base-rate 1e-5 --noise-attitude 1e-5"
    spaceid identify servicer-dual before.csv --momentum 1,-2,3 $NOISE -o before.json
    spaceid identify servicer-dual after.csv --momentum 1,-2,3 $NOISE -o after.json
    spaceid compare before.json after.json

``python examples/capture.py`` in the repository runs the same study on more samples.
"""

# %%
# Two recordings
# --------------
# Both runs follow one rich random Fourier motion (60 s, 12 harmonics on every joint: enough to
# excite all 496 parameters) with the same momentum, sampled 500 times (1500 equations), with
# white noise of 1e-5 rad on the angles and the attitude and 1e-5 rad/s on the rates. The
# sensors are taken as characterised, so the estimator (the default, maximum likelihood) is
# given these noise levels. Nothing is known of the target: both are identified with the
# servicer's own model, whose geometry is all that the regressor uses.

import matplotlib.pyplot as plt
import numpy as np

import spaceid
from spaceid.estimation import compare
from spaceid.motion import FourierTrajectory

h = np.array([1.0, -2.0, 3.0])  # inertial angular momentum [N m s]
before, after = spaceid.load_model("servicer-dual"), spaceid.load_model("servicer-captured")
rng = np.random.default_rng(0)
nj = before.n_joints
traj = FourierTrajectory(before.joints, 60.0, rng.uniform(-0.3, 0.3, (nj, 12)), rng.uniform(-0.3, 0.3, (nj, 12)))
times = np.linspace(0.0, 60.0, 500)
noise = spaceid.Noise(angle=1e-5, rate=1e-5, base_rate=1e-5, attitude=1e-5)

param = spaceid.minimal_parameters(before)
truth = {}
results = []
for k, model in enumerate((before, after)):
    true = spaceid.minimal_parameters(model)  # same geometry: same set, the model's own values
    assert true.definitions == param.definitions
    truth[model.name] = true.true_values
    log = spaceid.simulate(true, true.true_values, traj, times, h, model=model)
    log = spaceid.add_noise(log, angle=1e-5, rate=1e-5, seed=k)
    results.append(spaceid.identify(param, log, h, noise=noise))
    print(f"{model.name}: {model.mass:.1f} kg, cond(Y) = {results[-1].condition_number:.3g}")

# %%
# Comparing
# ---------
# ``compare`` gives a :class:`~spaceid.estimation.Comparison`: per parameter the change, the
# relative change and a z-score, the change divided by the combined standard error
# ``sqrt(std_before^2 + std_after^2)``; ``|z| > 3`` stands out from the estimation noise
# (``diff.changed()`` names those parameters, ``diff.to_dict()`` is what ``spaceid compare --json``
# prints).

diff = compare(*results)
z = diff.z
changed = np.flatnonzero(abs(z) > 3)
assert len(diff.changed()) == changed.size
print(f"{changed.size} of {len(diff.names)} parameters changed beyond 3 standard errors; the largest:")
for i in changed[np.argsort(-abs(z[changed]))][:8]:
    print(f"  {diff.names[i]:>6s}: {diff.before[i]:10.5g} -> {diff.after[i]:10.5g}  z = {z[i]:8.1f}")

# %%
# The parameter with the largest change, in physical terms (the start of its definition):

top = int(np.argmax(abs(z)))
print(f"{diff.names[top]} = {diff.definitions[top][:300]} ...")

# %%
# Here the truth is known, so the comparison can be checked: the true change of every
# parameter, in units of the same combined standard error, against the z-score from the two
# identifications. The two differ by the estimation noise, about one unit, so every parameter
# the capture really moved by more than ten standard errors is found, and the decisions at
# ``|z| > 3`` agree with the truth almost everywhere.

sd = np.hypot(results[0].std, results[1].std)
true_z = (truth[after.name] - truth[before.name]) / sd
agree = np.mean((abs(z) > 3) == (abs(true_z) > 3))
print(f"z - true z: mean {np.mean(z - true_z):+.2f}, std {np.std(z - true_z):.2f}")
print(f"decisions that agree with the truth: {100 * agree:.1f} %")
assert np.all(abs(z[abs(true_z) > 10]) > 3)
assert agree > 0.95 and 0.5 < np.std(z - true_z) < 2

fig, ax = plt.subplots(figsize=(6.4, 3.4), layout="constrained")
ax.plot(true_z, z, ".", color="tab:red")
lim = 1.1 * abs(np.concatenate([z, true_z])).max()
ax.plot([-lim, lim], [-lim, lim], color="0.5", linewidth=0.8)
ax.axhspan(-3, 3, color="0.85", label="|z| <= 3")
ax.set_xlabel("true change / combined std")
ax.set_ylabel("z-score from the identifications")
ax.legend(loc="upper left")
ax.set_title(f"{changed.size} of {len(diff.names)} parameters changed by the capture")
