"""Draw the figures of the figure pages at build time (``conf.py`` calls :func:`make_figures`).

One small Cepheus study gives every figure: the paper's exciting trajectory (Table 2), 35
samples with white noise on the measured signals, a maximum-likelihood identification, its
validation by re-simulation of a second, held-out motion (designed, seed 1, 101 noisy samples:
the fitting log itself would only re-check the fit), the same motion started at rest (zero momentum, the scale anchored
by a known parameter), and a Monte Carlo study on the same motion. The tracking figures come from
the Cepheus experiment on the digital twin (the same trajectory, seed 0), with the feed-forward
planned from the prior model and with the published PD loops alone. It takes under a minute and
is seeded, so the figures are the same at every build.
"""

import shutil
import tempfile
from pathlib import Path

import numpy as np

import spaceid
from spaceid.studies import plot_montecarlo, plot_parameters, plot_singular_values, plot_trajectory, plot_validation

MOMENTUM = np.array([0.0, 0.0, 0.4934])  # the paper's simulation study [N m s]
NOISE = 1e-4  # [rad] on angles, [rad/s] on rates
SAMPLES = 35
FIGURES = ("trajectory", "validation", "parameters", "parameters_anchored", "singular_values", "montecarlo",
           "tracking", "tracking_pd")


def make_figures(folder) -> dict:
    """Write ``FIGURES`` as PNG files into ``folder``; return ``{name: path}``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    model = spaceid.load_model("cepheus")
    param = spaceid.minimal_parameters(model)
    traj = spaceid.load_trajectory("paper-table2", joints=model.joints)
    times = spaceid.sample_times(traj.duration, SAMPLES)
    clean = spaceid.simulate(param, param.true_values, traj, times, MOMENTUM, model=model)
    measured = spaceid.add_noise(clean, angle=NOISE, rate=NOISE, seed=2)
    noise = spaceid.Noise(angle=NOISE, rate=NOISE, base_rate=NOISE)
    ident = spaceid.identify(param, measured, MOMENTUM, noise=noise)
    held_out = _held_out_motion(param, model)
    predicted = spaceid.validate(ident, held_out, momentum=MOMENTUM).predicted
    at_rest = spaceid.simulate(param, param.true_values, traj, times, np.zeros(3), model=model)
    at_rest = spaceid.add_noise(at_rest, angle=NOISE, rate=NOISE, seed=3)
    anchored = spaceid.identify(param, at_rest, np.zeros(3), noise=noise, known={"pi5": param.true_values[4]})

    fine = np.linspace(0.0, traj.duration, 1001)
    q, qd, qdd = traj.evaluate(fine)
    limits = {key: model.joint_limits(kind) for key, kind in (("qd", "velocity"), ("qdd", "acceleration"))}
    limits["q"] = np.stack([model.joint_limits("lower"), model.joint_limits("upper")], axis=1)
    study = spaceid.run_montecarlo(param, traj, momentum=MOMENTUM, noise=spaceid.Noise(angle=NOISE, rate=NOISE,
                                   base_rate=NOISE), samples=SAMPLES, runs=200, estimators=("ml", "ols"), jobs=1)
    paths = {name: folder / f"{name}.png" for name in FIGURES}
    plot_trajectory(fine, q, qd, qdd, model.joints, paths["trajectory"], limits=limits, times=times)
    plot_validation(held_out, predicted, paths["validation"])
    plot_parameters(ident, paths["parameters"], true=param.true_values)
    plot_parameters(anchored, paths["parameters_anchored"], true=param.true_values)
    plot_singular_values(ident, paths["singular_values"])
    plot_montecarlo(study, paths["montecarlo"])
    for name, feedforward in (("tracking", True), ("tracking_pd", False)):
        with tempfile.TemporaryDirectory() as report:  # the experiment's report draws it
            spaceid.run_experiment(trajectory=traj, seed=0, feedforward=feedforward, out=report)
            shutil.copyfile(Path(report) / "tracking.png", paths[name])
    return paths


def _held_out_motion(param, model):
    """A second, different motion to validate on: designed (seed 1, a short search), 101 samples, noisy."""
    traj = spaceid.design_excitation(param, duration=5.0, harmonics=3, samples=SAMPLES, momentum=MOMENTUM, seed=1,
                                     n_starts=4).trajectory
    log = spaceid.simulate(param, param.true_values, traj, spaceid.sample_times(traj.duration, 101), MOMENTUM,
                           model=model)
    return spaceid.add_noise(log, angle=NOISE, rate=NOISE, seed=4)
