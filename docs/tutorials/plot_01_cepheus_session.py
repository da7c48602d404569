"""
The Cepheus session: model, design, simulate, identify, validate
=================================================================

This tutorial walks through the whole pipeline on the planar emulator "Cepheus" (a base on air
bearings carrying a two-link arm), the system of the paper's simulation study. Each step is
one library call, and each has a command-line twin; the same session from a shell reads:

.. code-block:: bash

    spaceid model cepheus
    spaceid design cepheus --duration 5 --harmonics 3 --samples 35 --momentum 0.4934 --seed 1 -o traj.json
    spaceid simulate cepheus --trajectory traj.json --momentum 0.4934 --samples 35 \\
        --noise-angle 1e-4 --noise-rate 1e-4 --seed 2 -o log.csv
    spaceid identify cepheus log.csv --momentum 0.4934 -o result.json
    spaceid validate result.json log.csv --momentum 0.4934 --out validation/

The files it writes are described in :doc:`/formats/index`, the method in :doc:`/theory/index`.
"""

# %%
# The model and its minimal parameters
# ------------------------------------
# ``cepheus`` is a built-in model (a YAML description, see :doc:`/formats/yaml-model`). Its
# links declare their centres of mass to lie on the line through their joints, as in the
# paper's model, so the momentum depends on 8 combinations of the inertial parameters
# (:doc:`/theory/cepheus`). ``minimal_parameters`` derives them, with their definitions in
# physical terms and their values for this model (the truth of the simulation below).
# ``spaceid model cepheus`` prints the same report.

import shutil
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

import spaceid
from spaceid.data import write_json
from spaceid.studies import plot_validation

model = spaceid.load_model("cepheus")
param = spaceid.minimal_parameters(model)
print(f"{model.name}: joints {model.joints}, total mass {model.mass:.4g} kg, planar {model.planar}")
for name, value, definition in zip(param.names, param.true_values, param.definitions):
    print(f"{name} = {value:.6g}   = {definition}")

assert param.n_params == 8 and param.basis == "planar"

# %%
# The closed form of the paper's Appendix B gives the same numbers from Table 1. Here are the
# first and the last: :math:`\pi_1 = m_0 (m_1 l_1 + m_2 L_1) r_{0x} / M` and
# :math:`\pi_8 = I_2 + (m_0 + m_1) m_2 l_2^2 / M`.

m0, m1, m2 = 9.951, 0.083, 0.187
l1, r1, l2, r0x, i2 = 0.119, 0.062, 0.146, 0.17, 7.17e-4
M = m0 + m1 + m2
closed_form = [m0 * (m1 * l1 + m2 * (l1 + r1)) * r0x / M, i2 + (m0 + m1) * m2 * l2**2 / M]
print("closed form:", np.round(closed_form, 8), " derived:", np.round(param.true_values[[0, 7]], 8))
assert np.allclose(param.true_values[[0, 7]], closed_form, rtol=1e-9)

# %%
# An exciting trajectory
# ----------------------
# The joints follow a Fourier series plus a quintic that starts and ends at rest
# (:doc:`/theory/excitation`); its coefficients are searched so that the regressor stacked at
# the 35 samples is well conditioned, within the model's joint limits. The search is seeded:
# the same seed gives the same trajectory. The command line uses 64 local starts; 8 are enough
# here. ``momentum`` is the system's angular momentum in inertial axes [N m s] (the paper's
# 0.4934 about the vertical).

h = np.array([0.0, 0.0, 0.4934])
design = spaceid.design_excitation(param, duration=5.0, harmonics=3, samples=35, momentum=h, seed=1, n_starts=8)
traj = design.trajectory
print(f"criterion {design.criterion}: cond(Y) = {design.value:.4g} (the paper's Table 2 trajectory: about 360)")

folder = Path(tempfile.mkdtemp(prefix="spaceid-tutorial-"))  # any folder will do
traj.save(folder / "traj.json")
assert design.value < 40 and (folder / "traj.json").is_file()

# %%
# The designed motion keeps its limits at every instant, not only at the samples:

t_fine = np.linspace(0.0, traj.duration, 2001)
q, qd, qdd = traj.evaluate(t_fine)
peaks = {"|q| [rad]": abs(q).max(0), "|qd| [rad/s]": abs(qd).max(0), "|qdd| [rad/s^2]": abs(qdd).max(0)}
for label, peak in peaks.items():
    print(f"largest {label}: {np.round(peak, 3)}")
limits = [model.joint_limits("upper"), model.joint_limits("velocity"), model.joint_limits("acceleration")]
assert all(np.all(p <= lim * (1 + 1e-6)) for p, lim in zip(peaks.values(), limits))

fig, axes = plt.subplots(2, 1, sharex=True, figsize=(6.4, 4.2), layout="constrained")
for j, joint in enumerate(model.joints):
    axes[0].plot(t_fine, q[:, j], label=joint)
    axes[1].plot(t_fine, qd[:, j])
axes[0].set_ylabel("q [rad]")
axes[1].set_ylabel("qd [rad/s]")
axes[1].set_xlabel("t [s]")
axes[0].legend()
axes[0].set_title("Designed exciting trajectory")

# %%
# Simulate a measurement
# ----------------------
# ``simulate`` integrates the base motion that momentum conservation implies for the joint
# motion; ``add_noise`` then adds white noise of 1e-4 rad to the angles and 1e-4 rad/s to the
# rates, as a measurement would. The log is written as CSV (:doc:`/formats/log-csv`) and read
# back, like a recording from the lab.

times = spaceid.sample_times(traj.duration, 35)
clean = spaceid.simulate(param, param.true_values, traj, times, h, model=model)
print(f"momentum conserved to {clean.meta['momentum_rel_error']:.1e} (relative)")
noisy = spaceid.add_noise(clean, angle=1e-4, rate=1e-4, seed=2)
spaceid.write_log(folder / "log.csv", noisy)
log = spaceid.read_log(folder / "log.csv", joints=model.joints, planar=True)
print((folder / "log.csv").read_text().splitlines()[0])
assert clean.meta["momentum_rel_error"] < 1e-9 and log.n_samples == 35

# %%
# Identify
# --------
# ``identify`` estimates the 8 parameters from the log and the known momentum. The default
# estimator is maximum likelihood for the errors-in-variables problem (:doc:`/theory/noise`);
# since no noise levels are given, they are estimated from the log itself, and the residuals
# set the overall scale of the covariance.

result = spaceid.identify(param, log, h)
rel = (result.values - param.true_values) / param.true_values
for name, value, std, err in zip(result.names, result.values, result.std, rel):
    print(f"{name}: {value:.6g} +/- {std:.2g}   error {100 * err:+.3f} %")
print(f"cond(Y) = {result.condition_number:.4g}, residual RMS {result.residual_rms:.2g} N m s, "
      f"noise {result.settings['noise']['source']}")
assert np.all(abs(rel) < 0.01)  # better than 1 % on every parameter at this noise level

# %%
# The result draws itself: ``result.plot()`` returns a matplotlib figure of the estimates with
# their 2-sigma error bars (relative to the truth when given; ``kind="singular_values"`` for the
# regressor's singular values), on new axes or on the ones given. How well the data agreed with
# the model is in ``result.diagnostics`` (:class:`~spaceid.estimation.Diagnostics`).

fig, ax = plt.subplots(figsize=(6.4, 3.6), layout="constrained")
assert result.plot(ax=ax, true=param.true_values) is fig
d = result.diagnostics
print(f"chi2/dof = {d.chi2_dof:.3g}; covariance: {d.covariance_method}; {d.plausibility}; "
      f"unmodelled drift: {d.drift_test.drift}")
assert not d.drift_test.drift

# %%
# The result is saved as JSON (:doc:`/formats/result-json`); ``load_identified`` reads it back
# as the identified model (``load_result`` as the bare record).

write_json(folder / "result.json", result.to_dict())
again = spaceid.load_identified(folder / "result.json")
assert np.allclose(again.values, result.values, rtol=0, atol=1e-15)

# %%
# Validate
# --------
# The identified parameters are all that is needed to re-simulate the system: ``validate``
# drives the identified model with the measured joint motion from the measured initial
# attitude and compares the base motion it predicts with the measured one (the paper's Fig. 6;
# see :doc:`/figures/validation`).

check = spaceid.validate(again, log, momentum=h)  # a spaceid.studies.Validation
predicted, metrics = check.predicted, check.metrics
for key, value in metrics.items():
    print(f"{key:>12s} = {value:.3g}")
assert metrics["base_w_nrms"] < 1e-3  # the noise level, not a model error

# %%
# The validation draws itself too: measured against predicted base motion, the residuals below
# (a figure of several panels: ``check.plot()`` makes its own, ``check.plot(fig=...)`` fills the
# figure or subfigure given).

check.plot(fig=plt.figure(figsize=(7.2, 4.6), layout="constrained"))

# %%
# ``spaceid validate`` also writes ``predicted.csv``, ``metrics.json`` and ``report.html`` into its
# output folder, and ``validation.png`` with ``--png``; ``plot_validation`` draws that figure, and
# writes it when given a path:

plot_validation(log, predicted, folder / "validation.png")
assert (folder / "validation.png").stat().st_size > 10_000

# %%
# Model-based control
# -------------------
# ``again`` is more than the numbers: ``spaceid.load_identified`` gives the identified model with
# the free-floating dynamics its parameters fix (:doc:`/theory/control`): the joints' inertia
# with the base free to move, ``H*(q)``, with its standard deviations from the covariance of
# the parameters, and the joint accelerations under motor torques with the momentum conserved.

q0 = log.q[0]
reduced = again.reduced_inertia(q0)
spread = np.sqrt(np.einsum("ijij->ij", again.reduced_inertia_cov(q0)))
print(f"H*(q0) [kg m^2]:\n{reduced}\nstandard deviations:\n{spread}")
qdd = again.forward_dynamics(q0, log.qd[0], np.array([0.01, 0.0]), momentum=h)
print(f"accelerations under 0.01 N m on {model.joints[0]}: {qdd} rad/s^2")
print("not fixed by the parameters:", ", ".join(again.undetermined))
exact = spaceid.identified.identified_model(spaceid.identify(param, clean, h)).reduced_inertia(q0)
assert np.abs(reduced - exact).max() < 0.01 * np.abs(exact).max()

# %%
# The files of this tutorial went into a temporary folder; remove it.

shutil.rmtree(folder)
