"""
A captured payload: its mass, centre of mass and inertia
========================================================

After a capture the servicer carries an object it knows little about. With the servicer's own
model known (a CAD model, or the URDF that ``spaceid export`` wrote from an earlier
identification), a log recorded after the capture gives the object's mass, centre of mass and
inertia, with standard errors, physically consistent, and without a scale anchor: the servicer's
known bodies fix the scale, so a capture from rest works (:doc:`/theory/payload`).

The planar example is Cepheus holding a 0.3 kg object in its end effector (``link2``). From a
shell, with a log recorded after the grasp:

.. code-block:: bash

    spaceid design cepheus --duration 20 --harmonics 3 --samples 200 --momentum 0 \\
        --payload-link link2 --noise-angle 1e-4 --noise-rate 1e-4 --noise-base-rate 1e-4 -o traj.json
    spaceid payload cepheus after.csv --link link2 --momentum 0 --noise-angle 1e-4 \\
        --noise-rate 1e-4 --noise-base-rate 1e-4 -o payload.json

The spatial example, the dual-arm servicer and the ``servicer-captured`` preset's target, closes
the page.
"""

# %%
# The grasp, simulated
# --------------------
# ``payload_map`` ties the payload's parameters on ``link2`` to the servicer's minimal
# parameters; its ``model`` is the servicer holding a given payload, which here plays the truth.
# The payload: 0.3 kg, its CoM 5 cm along the link and 1 cm across it, 7.8e-4 kg m^2 about its
# CoM. The system starts from rest (zero momentum), and a 20 s random Fourier motion is sampled
# 200 times with white noise of 1e-4 rad and rad/s on every signal.

import matplotlib.pyplot as plt
import numpy as np

import spaceid
from spaceid.identified import payload_map
from spaceid.motion import FourierTrajectory

pmap = payload_map("cepheus", "link2")
mass, com, izz = 0.3, np.array([0.05, 0.01]), 7.8e-4
theta = np.array([mass, *(mass * com), izz + mass * com @ com])  # m, mcx, mcy, Izz about link2's origin
truth = np.array([mass, *com, izz])

rng = np.random.default_rng(1)
model = pmap.param.model
traj = FourierTrajectory(model.joints, 20.0, rng.uniform(-0.3, 0.3, (2, 3)), rng.uniform(-0.3, 0.3, (2, 3)))
h = np.zeros(3)  # a capture from rest
clean = spaceid.simulate(pmap.param, pmap.pi(theta), traj, np.linspace(0, 20, 200), h, model=pmap.model(theta))
noise = spaceid.Noise(angle=1e-4, rate=1e-4, base_rate=1e-4)

# %%
# Identifying it
# --------------
# ``identify_payload`` fits the payload by Gauss-Newton on the momentum equations (they are not
# linear in the payload's mass, which the total mass holds), weighted by the errors-in-variables
# noise model. Planar motion shows the mass, the CoM in the plane and Izz about the CoM; the rest
# is named as not identifiable.

log = spaceid.add_noise(clean, angle=1e-4, rate=1e-4, seed=0)
est = spaceid.identify_payload(pmap, log, "link2", h, noise=noise)
z = (est.values - truth) / est.std
for name, v, e, t, zi in zip(est.names, est.values, est.std, truth, z):
    print(f"{name:>4s} = {v:11.6g} +/- {e:.2g}   (truth {t:.6g}, z = {zi:+.2f})")
print("not identifiable:", ", ".join(est.not_identifiable))
print(f"{est.settings['gauss_newton_steps']} Gauss-Newton steps, chi2/dof = {est.settings['chi2_dof']:.3f}")
assert np.all(abs(z) < 4) and est.not_identifiable[0] == "cz"

# %%
# The estimate draws itself, a panel per parameter with one standard error, against the truth
# when it is given (here the simulation's; the z-scores in the panels' titles):

est.plot(fig=plt.figure(figsize=(8.6, 3.0), layout="constrained"), true=dict(zip(est.names, truth)))

# %%
# Are the standard errors right?
# ------------------------------
# Forty more noise draws: the spread of the estimates against the standard error each run
# reports. The normalised errors should scatter like a standard normal.

runs = [spaceid.identify_payload(pmap, spaceid.add_noise(clean, angle=1e-4, rate=1e-4, seed=s), "link2", h,
                                 noise=noise) for s in range(1, 41)]
values = np.array([r.values for r in runs])
std = np.mean([r.std for r in runs], 0)
ratio = values.std(0) / std
for name, r in zip(est.names, ratio):
    print(f"{name:>4s}: spread / reported std = {r:.2f}")
assert np.all(abs(ratio - 1) < 0.35)

fig, ax = plt.subplots(figsize=(6.4, 3.2), layout="constrained")
for i, name in enumerate(est.names):
    zs = (values[:, i] - truth[i]) / std[i]
    ax.plot(np.full(len(zs), i) + rng.uniform(-0.15, 0.15, len(zs)), zs, ".", alpha=0.7)
ax.axhspan(-2, 2, color="0.9")
ax.set_xticks(range(len(est.names)), est.names)
ax.set_ylabel("(estimate - truth) / std")
ax.set_title("Cepheus' payload over 40 noise draws")

# %%
# The spatial case: the dual-arm servicer and its target
# ------------------------------------------------------
# ``servicer-captured`` is ``servicer-dual`` holding a 150 kg defunct satellite 0.2 m beyond its
# left flange (the fixed joint ``capture`` from ``left_ee``, turned 0.35 rad about z). With
# ``servicer-dual`` as the known servicer and the tool link ``left_ee`` named (a link on a fixed
# joint: the result is in its frame), a 30 s motion from rest sampled 150 times, with noise of
# 1e-5 on every signal, gives all ten parameters. This takes about 25 s (the servicer's 496-parameter
# minimal set is derived once), so it is not run here:
#
# .. code-block:: python
#
#     before, after = spaceid.load_model("servicer-dual"), spaceid.load_model("servicer-captured")
#     param = spaceid.minimal_parameters(after)
#     rng = np.random.default_rng(0)
#     traj = FourierTrajectory(before.joints, 30.0, rng.uniform(-0.1, 0.1, (14, 4)), rng.uniform(-0.1, 0.1, (14, 4)))
#     log = spaceid.simulate(param, param.true_values, traj, np.linspace(0, 30, 150), np.zeros(3), model=after)
#     log = spaceid.add_noise(log, angle=1e-5, rate=1e-5, seed=0)
#     noise = spaceid.Noise(angle=1e-5, rate=1e-5, base_rate=1e-5, attitude=1e-5)
#     est = spaceid.identify_payload(before, log, "left_ee", [0, 0, 0], noise=noise)
#
# Against the target's values in ``left_ee``'s frame (its URDF CoM and inertia, moved by the
# ``capture`` joint), measured:
#
# .. code-block:: text
#
#        m =  149.99612 +/- 0.0077   truth  150.00000   z = -0.51
#       cx =    0.04043 +/- 2.7e-05   truth    0.04042   z = +0.32
#       cy =   -0.00865 +/- 3e-05    truth   -0.00866   z = +0.52
#       cz =    0.75999 +/- 3.2e-05   truth    0.76000   z = -0.31
#      Ixx =   18.44713 +/- 0.0064   truth   18.45002   z = -0.45
#      Ixy =   -0.00066 +/- 0.0051   truth    0.00156   z = -0.44
#      Iyy =   18.30405 +/- 0.0098   truth   18.30778   z = -0.38
#      Ixz =   -0.00475 +/- 0.0037   truth   -0.00820   z = +0.94
#      Iyz =    0.74393 +/- 0.0046   truth    0.74560   z = -0.37
#      Izz =   14.54951 +/- 0.0071   truth   14.54230   z = +1.01
#     wls (Gauss-Newton, errors-in-variables weights) 6 steps, chi2/dof 1.018
#
# Noise-free, the same call recovers the target to 1e-8 (``tests/test_payload.py``). From a
# shell: ``spaceid payload servicer-dual after.csv --link left_ee --momentum 0 ...``.
