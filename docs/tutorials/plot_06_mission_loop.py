"""
The mission loop: from identified parameters to a controller
============================================================

Identification is a means: a free-floating robot is identified so that its controllers and its
simulators know its dynamics. This tutorial closes that loop on Cepheus with its reaction
wheel (``cepheus-rw``): identify the minimal parameters and the system CM from a noisy log,
export a physically consistent model close to a CAD prior that is 20-30 % off, compute the
free-floating joint inertia ``H*`` and the generalized Jacobian, and let the twin's arm track a
motion with a computed-torque feed-forward planned from each model: the true one, the
identified one and the CAD prior. From a shell, the first steps are:

.. code-block:: bash

    spaceid design cepheus-rw --duration 10 --harmonics 3 --samples 100 --momentum 0.5 \\
        --q-max 1 --qdd-max 3 -o traj.json
    spaceid simulate cepheus-rw --trajectory traj.json --momentum 0.5 --noise-angle 1e-4 \\
        --noise-rate 1e-4 --base-position -o log.csv
    spaceid identify cepheus-rw log.csv --momentum 0.5 --noise-angle 1e-4 --noise-rate 1e-4 \\
        --com -o result.json
    spaceid export result.json --prior cad.yaml --region 0.95 -o identified.urdf

and in Python ``spaceid.load_result("result.json")`` gives the controller-ready model
(:doc:`/theory/control`).
"""

# %%
# Identification, with the base position
# --------------------------------------
# The log is simulated rather than recorded on the twin: the twin's protocol (spin-up,
# excitation, bag, identification; :doc:`/auto_tutorials/plot_04_twin_experiment`) takes over
# half a minute even on the ideal twin, most of this page's time budget, and what this tutorial
# shows starts from its result. The system carries 0.5 N m s of angular momentum and follows a
# 30 s random Fourier motion of all three joints, sampled 600 times, with white noise of 0.1 mrad
# on the angles and 0.1 mrad/s on the rates; motion capture adds 1 mm of noise to the base
# position. Zero linear momentum keeps the system CM in place, so the base position
# identifies the CM terms that angular momentum leaves free (``identify_com``).

import tempfile
from dataclasses import replace
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import yaml

import spaceid
from spaceid.identified import (
    export_model,
    identified_model,
    identify_com,
    write_export,
)
from spaceid.motion import FourierTrajectory
from spaceid.twin import TwinSettings, planned_feedforward

truth = spaceid.load_model("cepheus-rw")
param = spaceid.minimal_parameters(truth)
h = np.array([0.0, 0.0, 0.5])  # inertial angular momentum [N m s]
rng = np.random.default_rng(0)
excitation = FourierTrajectory(truth.joints, 30.0, rng.uniform(-0.3, 0.3, (3, 5)), rng.uniform(-0.3, 0.3, (3, 5)))
times = np.linspace(0.0, 30.0, 600)
exact = spaceid.simulate(param, param.true_values, excitation, times, h, model=truth, base_position=True)
log = spaceid.add_noise(exact, angle=1e-4, rate=1e-4, seed=1)
log = replace(log, base_position=log.base_position + np.r_[1e-3, 1e-3, 0] * rng.standard_normal((len(times), 3)))
noise = spaceid.Noise(angle=1e-4, rate=1e-4, base_rate=1e-4, attitude=1e-4)
identified = identify_com(identified_model(spaceid.identify(param, log, h, noise=noise)), log)

rel = (identified.values - param.true_values) / abs(param.true_values)
print(f"{param.n_params} parameters, cond(Y) = {identified.condition_number:.3g}; worst relative error "
      f"{100 * abs(rel).max():.2g} % ({param.names[int(np.argmax(abs(rel)))]})")
com = identified.identification.com
print(f"{len(com['names'])} CM terms from the base position, residual {1e3 * com['residual_rms']:.2f} mm RMS")
assert abs(rel).max() < 0.01 and com["residual_rms"] < 2e-3

# %%
# A CAD prior that is off, and the exported model
# -----------------------------------------------
# The CAD model is the preset with every body's mass and inertia scaled by a seeded factor
# between 0.7 and 0.8 or between 1.2 and 1.3 (its geometry and CoMs kept), written as a YAML
# robot description. ``export_model`` finds the standard parameters of every body that are
# physically consistent, reproduce the identified ``pi`` and stay closest to the prior in the
# log-det divergence of pseudo-inertias. Here the noisy estimate is not exactly realisable by
# positive masses and inertias, so the export searches its 95 % confidence ellipsoid
# (``--region 0.95``); it writes a URDF that any simulator loads.

folder = Path(tempfile.mkdtemp(prefix="spaceid-mission-"))
preset = yaml.safe_load((Path(spaceid.__file__).parent / "models" / "presets" / "cepheus-rw.yaml").read_text())
factor = np.random.default_rng(2).choice([-1.0, 1.0], (4, 2)) * np.random.default_rng(3).uniform(0.2, 0.3, (4, 2))
for body, (fm, fi) in zip(preset["bodies"], 1 + factor):
    body["mass"] = float(body["mass"] * fm)
    body["inertia"] = {k: float(v * fi) for k, v in body["inertia"].items()}  # one factor: still a rigid body
preset["name"] = "cepheus-cad"
(folder / "cad.yaml").write_text(yaml.safe_dump(preset, sort_keys=False))
cad = spaceid.load_model(folder / "cad.yaml")

export = export_model(identified.identification, cad, region=0.95, prior_name="cad.yaml")
write_export(export, folder / "identified.urdf")
exported = spaceid.load_model(folder / "identified.urdf", planar=True)
print(f"exported: Mahalanobis distance {export.mahalanobis:.3g} (bound {export.bound:.3g}), divergence from the "
      f"prior {export.divergence:.3g}")
for change, true_body in zip(export.changes(), truth.bodies):
    print(f"  {change['body']:>6s}: mass {change['mass_prior']:.4g} (CAD) -> {change['mass']:.4g} kg "
          f"(true {true_body.mass:.4g}), inertia changed {100 * change['inertia_change']:.0f} %")
assert export.mahalanobis <= export.bound * (1 + 1e-6)
arm_changes = zip(export.changes()[2:], truth.bodies[2:])  # link1, link2: closer to the truth than the CAD
assert all(abs(c["mass"] - b.mass) < abs(c["mass_prior"] - b.mass) for c, b in arm_changes)

# %%
# The data moved the arm links' masses from the CAD values to within a few percent of the true
# ones (7 % and 3 %). The base and wheel masses stay near the prior: the planar momentum does not
# see the total mass, only the combinations that ``pi`` holds, which the export reproduces.

# %%
# Three models for a controller
# -----------------------------
# A controller needs the free-floating joint dynamics ``H*(q) qdd = tau - b(q, qd)``, with ``H*``
# the joint inertia when the base moves so that the momentum stays zero. ``IdentifiedModel``
# gives ``reduced_inertia`` (``H*``) and ``bias_torque`` (``b``) from any ``pi``; the same
# parameter set evaluated at the true and at the CAD inertial values gives the other two models.
# ``H*`` of the identified model is within its standard error of the truth (the covariance
# propagated from that of ``pi``); the CAD prior's is off by tens of percent.


def with_values(model, pi):
    """``model`` (an IdentifiedModel) with the minimal parameters ``pi`` instead of its estimate."""
    return type(model)(replace(model.identification, values=np.asarray(pi, float)), model.param)


models = {
    "true": with_values(identified, param.true_values),
    "identified": identified,
    "CAD prior": with_values(identified, spaceid.minimal_parameters(cad).true_values),
}
q_test = np.array([0.0, 0.6, -0.9])  # wheel, shoulder, elbow [rad]
h_true = models["true"].reduced_inertia(q_test)
std = np.sqrt(np.einsum("ijij->ij", identified.reduced_inertia_cov(q_test)))
for name, m in models.items():
    err = np.linalg.norm(m.reduced_inertia(q_test) - h_true) / np.linalg.norm(h_true)
    print(f"{name:>10s}: |H* - H*_true| / |H*_true| = {err:.2e}")
z = abs(identified.reduced_inertia(q_test) - h_true) / std
print(f"identified H* - true: at most {z.max():.2g} of its standard errors")
assert z.max() < 5

# %%
# The generalized Jacobian
# ------------------------
# With the CM terms, ``generalized_jacobian`` maps joint rates to a frame's inertial velocity at
# zero momentum, the base's reaction included (Umetani and Yoshida): what resolved-rate
# end-effector control inverts. The preset has no tool frame; a point 0.3 m along ``link2``
# stands in for the gripper. The true model's CM terms come from the noise-free log, the CAD
# prior's from the base path the CAD model itself predicts for the same joint motion.

tool = np.array([0.3, 0.0, 0.0])  # [m] in link2 axes
cad_param = spaceid.minimal_parameters(cad)
cad_log = spaceid.simulate(cad_param, cad_param.true_values, excitation, times, h, model=cad, base_position=True)
models["true"] = identify_com(models["true"], exact)
models["CAD prior"] = identify_com(models["CAD prior"], cad_log)
jac = {name: m.generalized_jacobian(log.q, "link2", point=tool) for name, m in models.items()}
tool_speed = {name: (j @ log.qd[..., None])[:, :2, 0] for name, j in jac.items()}  # linear x, y [m/s]
for name, v in tool_speed.items():
    print(f"{name:>10s}: tool velocity error {1e3 * np.sqrt(np.mean((v - tool_speed['true']) ** 2)):.3g} mm/s RMS "
          f"(tool speed {1e3 * np.sqrt(np.mean(tool_speed['true'] ** 2)):.3g} mm/s RMS)")
assert np.sqrt(np.mean((tool_speed["identified"] - tool_speed["true"]) ** 2)) < 0.1 * np.sqrt(
    np.mean((tool_speed["CAD prior"] - tool_speed["true"]) ** 2))

fig, ax = plt.subplots(figsize=(6.4, 3.0), layout="constrained")
for name, color in (("identified", "tab:red"), ("CAD prior", "tab:blue")):
    gap = np.linalg.norm(tool_speed[name] - tool_speed["true"], axis=1)
    ax.semilogy(times, 1e3 * np.maximum(gap, 1e-9), color=color, label=f"{name} - true")
ax.set_xlabel("t [s]")
ax.set_ylabel("tool velocity error [mm/s]")
ax.legend()
ax.set_title("Tool velocity from the generalized Jacobian, against the true model's")

# %%
# Computed torque on the twin
# ---------------------------
# The twin's arm joints run the robot's soft PD loops (p = 0.1 N m/rad), which alone follow a
# motion with errors of a tenth of a radian. A lab adds a feed-forward computed offline from its
# model along the reference, ``inverse_dynamics``: ``tau = H*(q_r) qdd_r + b(q_r, qd_r)`` with the
# wheel held still and zero momentum (the twin starts at rest). For the true model this is the twin's own inverse
# dynamics, which ``planned_feedforward`` computes with Pinocchio; given the exported URDF it
# plans from the consistent model a simulator would load. Each feed-forward drives the ideal twin
# (effects off: no friction the models do not know) along a 10 s motion of the arm; the error is
# the twin's true joint angle minus the reference, at 1 kHz.

settings = TwinSettings().without_effects()
arm = ("left_shoulder", "left_elbow")
motion = FourierTrajectory(arm, 10.0, np.random.default_rng(4).uniform(-0.4, 0.4, (2, 4)),
                           np.random.default_rng(5).uniform(-0.4, 0.4, (2, 4)))


def reference(t):
    """Arm set points ``(q, qd, qdd)`` (n, 2) at phase times ``t`` [s], held after the motion."""
    return motion.evaluate(np.minimum(np.asarray(t, float), motion.duration))


def computed_torque(model):
    """Feed-forward efforts [N m] (n, 2) of the arm at phase times ``t``, planned from ``model``."""

    def effort(t):
        with_wheel = [np.hstack([np.zeros((len(t), 1)), x]) for x in reference(t)]  # wheel at rest
        return model.inverse_dynamics(*with_wheel, momentum=np.zeros(3))[:, 1:]

    return effort


t_plan = np.linspace(0.0, 10.0, 101)
pinocchio_plan = planned_feedforward(reference, t_plan, settings=settings)
gap = abs(computed_torque(models["true"])(t_plan) - pinocchio_plan).max()
print(f"H* and b of the true pi vs Pinocchio's inverse dynamics: {gap:.1e} N m (efforts up to "
      f"{abs(pinocchio_plan).max():.3f} N m)")
assert gap < 1e-9

laws = {name: computed_torque(m) for name, m in models.items()}
laws["exported URDF"] = lambda t: planned_feedforward(reference, t, settings=settings, model=exported)
laws["PD only"] = None
plans = {name: laws[name](t_plan) for name in ("identified", "exported URDF", "CAD prior")}
for name in ("exported URDF", "CAD prior"):
    print(f"{name} plan - identified plan: {abs(plans[name] - plans['identified']).max():.1e} N m")
gaps = {name: abs(plan - plans["identified"]).max() for name, plan in plans.items()}
assert gaps["exported URDF"] < 0.01 * gaps["CAD prior"]
errors, rms = {}, {}
for name, law in laws.items():
    run = spaceid.run_twin(reference, duration=motion.duration, settings=settings, seed=7, effort=law)
    columns = [run.truth.joints.index(j) for j in arm]
    errors[name] = run.truth.q[:, columns] - reference(run.truth.t - run.truth.t[0])[0]
    rms[name] = np.sqrt(np.mean(errors[name] ** 2, axis=0))
t_run = run.truth.t - run.truth.t[0]

print(f"{'feed-forward':>14s}  {'shoulder':>9s}  {'elbow':>9s}   tracking RMS [mrad]")
for name, (shoulder, elbow) in rms.items():
    print(f"{name:>14s}  {1e3 * shoulder:9.3f}  {1e3 * elbow:9.3f}")
assert np.all(rms["identified"] < 1.5 * rms["true"]) and np.all(rms["exported URDF"] < 1.5 * rms["true"])
assert np.all(rms["CAD prior"] > 10 * rms["identified"]) and np.all(rms["PD only"] > rms["CAD prior"])

# %%
# With the identified model the arm tracks as well as with the true one: what is left is the
# PD loops' lag behind the digital controller's held efforts, the same for both. The CAD prior's
# errors are more than a hundred times larger, and without a feed-forward the arm is off by a tenth
# of a radian. The exported URDF, planned through Pinocchio, gives nearly the efforts of ``H*``
# and ``b`` of the identified ``pi`` (its own ``pi`` is inside the estimate's confidence
# ellipsoid), and tracks as well.

fig, axes = plt.subplots(2, 1, sharex=True, figsize=(6.4, 4.6), layout="constrained")
styles = {"true": ("0.2", "-"), "identified": ("tab:red", "--"), "exported URDF": ("tab:orange", ":"),
          "CAD prior": ("tab:blue", "-"), "PD only": ("0.6", "-")}
for c, (ax, joint) in enumerate(zip(axes, arm)):
    for name, err in errors.items():
        color, line = styles[name]
        ax.semilogy(t_run, np.maximum(abs(err[:, c]), 1e-7), color=color, linestyle=line, linewidth=0.9, label=name)
    ax.set_ylabel(f"|{joint} error| [rad]")
    ax.set_ylim(1e-6, 1)
axes[-1].set_xlabel("t [s]")
axes[0].legend(fontsize=8, ncol=5, loc="lower left", bbox_to_anchor=(0, 1.0), frameon=False, columnspacing=1.0)
fig.suptitle("Twin arm tracking with the feed-forward planned from each model")
