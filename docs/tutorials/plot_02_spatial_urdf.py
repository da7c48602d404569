"""
A spatial robot from URDF: a 7-DOF arm on a satellite
=====================================================

Any URDF tree on a floating root link works like Cepheus, in three dimensions: the base
attitude becomes a quaternion, the momentum a 3-vector and every sample gives three equations.
This tutorial loads the ``satellite-7dof`` example (a 500 kg bus carrying a 7-joint arm; an
illustrative model shipped with spaceid, not a real spacecraft), reads its identifiability
report, designs an exciting motion within the joint limits and identifies the parameters from
noise-free data. From a shell:

.. code-block:: bash

    spaceid model satellite-7dof
    spaceid design satellite-7dof --duration 90 --harmonics 8 --samples 300 --momentum 1,-2,3 \\
        --starts 8 -o traj.json
    spaceid simulate satellite-7dof --trajectory traj.json --momentum 1,-2,3 --samples 300 -o log.csv
    spaceid identify satellite-7dof log.csv --momentum 1,-2,3 --estimator ols -o result.json

The limits default to the model's: angle and rate from each URDF ``<limit>`` tag, and the
joint acceleration from its ``acceleration`` attribute (an extension that Pinocchio ignores; the
presets give 0.5-1 rad/s², about half the joint torque over the largest inertia the joint
drives). ``--q-max``, ``--qd-max`` and ``--qdd-max`` override them with one value for every
joint; the library takes one value per joint.

Settings that work for this robot (``--momentum 1,-2,3``, seed 0, 8 starts, the model's
limits; measured on the 2-core development machine while it was shared, so the times are
indicative):

============  =========  =======  ======================  =========
duration [s]  harmonics  samples  designed cond(Y)         wall time
============  =========  =======  ======================  =========
30            6          120      42,246                  31 s
60            6          200      3,005                   71 s
60            8          240      959                     51 s
90            6          240      718                     69 s
90            8          300      417                     93 s
============  =========  =======  ======================  =========

Longer motions with more harmonics excite more: the arm's small distal links need time at
their rate limits to show in the momentum. The default 64 starts take several minutes.

"""

# %%
# Loading the URDF
# ----------------
# The presets are files inside the package; a path to any URDF loads the same way. The root
# link floats (spaceid adds the free-flyer joint), fixed joints are merged into their parent
# link (here the 3 kg tool on the flange), and each moving joint becomes a body.

from importlib import resources

import matplotlib.pyplot as plt
import numpy as np

import spaceid
from spaceid.dynamics import identifiability

urdf = resources.files("spaceid.models.presets") / "satellite-7dof.urdf"
model = spaceid.load_model(urdf)
print(f"{model.name}: {len(model.bodies)} bodies, {model.n_joints} joints, total mass {model.mass:.4g} kg, "
      f"planar {model.planar}")
for body in model.bodies:
    print(f"  {body.name:12s} parent {model.bodies[body.parent].name if body.parent >= 0 else '-':12s} "
          f"joint {body.joint or '(floating base)':18s} {body.mass:8.3f} kg")
assert model.n_joints == 7 and not model.planar

# %%
# The identifiability report
# --------------------------
# The minimal parameter set is found numerically (:doc:`/theory/general-tree`): 10 standard
# inertial parameters per body, the lumped products of masses and first moments over the total
# mass, and of those the combinations the momentum actually depends on. Each parameter is one
# full parameter plus the dependent ones it absorbs; its definition is a SymPy expression.
# ``identifiability`` says what the set tells about the physical parameters and whether it
# fixes the reduced dynamics. ``spaceid model satellite-7dof`` prints the same.

param = spaceid.minimal_parameters(model)
report = identifiability(param)
n_full = len(spaceid.dynamics.full_parameter_names(model))
print(f"standard parameters: {10 * len(model.bodies)}; with the lumped products: {n_full}; "
      f"minimal set: {param.n_params} (basis '{param.basis}', rank tolerance {param.rank_tol:g}, seed {param.seed})")
print(f"pi1 = {param.definitions[0][:240]} ...")
print(f"no effect on the momentum: {len(report.no_effect)}; identifiable alone: "
      f"{len(report.individually_identifiable)}; only in combinations: {len(report.in_combinations)}")
print(f"determines the reduced dynamics: {report.determines_dynamics} "
      f"(energy residual {report.energy_residual:.1e})")
assert param.n_params == 153 and param.basis == "columns" and report.determines_dynamics

# %%
# A design within the joint limits
# --------------------------------
# Spatial regressors have many columns whose singular values spread over decades, so a random
# motion is poorly conditioned and the design matters. Each sample gives three equations, so
# 120 samples over 30 s (360 equations for 153 unknowns) with 6 harmonics are enough to
# identify. The limits are the model's (passed here explicitly, one value per joint, to show
# the form: leave them out to get the same). Two local starts of 10 steps keep this tutorial
# short; the table above and :doc:`/benchmarks` show what longer searches reach.

h = np.array([1.0, -2.0, 3.0])  # inertial angular momentum [N m s]
q_max = np.fmin(abs(model.joint_limits("lower")), abs(model.joint_limits("upper")))
qd_max = model.joint_limits("velocity")
qdd_max = model.joint_limits("acceleration")
design = spaceid.design_excitation(param, duration=30.0, harmonics=6, samples=120, momentum=h, seed=0,
                                   q_max=q_max, qd_max=qd_max, qdd_max=qdd_max, n_starts=2, max_steps=10)
traj = design.trajectory
print(f"cond(Y): {traj.meta['start_value']:.3g} at the start of the search, {design.value:.3g} designed "
      f"({traj.meta['method']}, {design.wall_time:.0f} s)")
assert design.value < 0.1 * traj.meta["start_value"]

t_fine = np.linspace(0.0, traj.duration, 4001)
q, qd, qdd = traj.evaluate(t_fine)
ratio = max((abs(x).max(0) / lim).max() for x, lim in ((q, q_max), (qd, qd_max), (qdd, qdd_max)))
print(f"largest |signal| / limit over 4001 instants: {ratio:.6f}")
assert ratio <= 1 + 1e-6

fig, ax = plt.subplots(figsize=(6.4, 3.2), layout="constrained")
ax.plot(t_fine, qd / qd_max)
ax.set_xlabel("t [s]")
ax.set_ylabel("qd / qd_max")
ax.set_title("Joint rates of the design, as fractions of their limits")

# %%
# Noise-free identification
# -------------------------
# On noise-free data the estimate must equal the model's own parameter values up to round-off
# amplified by the condition number. Some parameters are tiny (products of small first moments
# over the total mass), so the error is measured against the largest parameter. Ordinary least
# squares needs no noise model and is the fast choice here.

times = spaceid.sample_times(traj.duration, 120)
log = spaceid.simulate(param, param.true_values, traj, times, h, model=model)
result = spaceid.identify(param, log, h, estimator="ols")
err = abs(result.values - param.true_values)
scale = abs(param.true_values).max()
print(f"momentum conserved to {log.meta['momentum_rel_error']:.1e}; cond(Y) = {result.condition_number:.3g}")
print(f"largest error / largest parameter: {err.max() / scale:.1e}")
assert log.meta["momentum_rel_error"] < 1e-9
assert err.max() < 1e-8 * scale

fig, ax = plt.subplots(figsize=(6.4, 3.2), layout="constrained")
ax.semilogy(np.arange(1, param.n_params + 1), np.maximum(err / scale, 1e-17), ".")
ax.set_xlabel("parameter index")
ax.set_ylabel("|error| / max |pi|")
ax.set_title(f"Noise-free identification, {param.n_params} parameters")
