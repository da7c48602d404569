"""Draw the figures of the figure pages at build time (``conf.py`` calls :func:`make_figures`).

One small Cepheus study gives every figure: the paper's exciting trajectory (Table 2), 35
samples with white noise on the measured signals, a maximum-likelihood identification, its
validation by re-simulation of a second, held-out motion (designed, seed 1, 101 noisy samples:
the fitting log itself would only re-check the fit), the same motion started at rest (zero momentum, the scale anchored
by a known parameter), and a Monte Carlo study on the same motion. The tracking figures come from
the Cepheus experiment on the digital twin (the same trajectory, seed 0), with the feed-forward
planned from the prior model and with the published PD loops alone. The many-parameter figures come
from satellite-7dof (153 parameters) on a seeded random motion: one identification and a 10-run Monte
Carlo study. It takes about a minute and is seeded, so the figures are the same at every build.
"""

import shutil
import tempfile
import warnings
from pathlib import Path

import numpy as np

import spaceid
from spaceid.studies import plot_montecarlo, plot_parameters, plot_singular_values, plot_trajectory, plot_validation

MOMENTUM = np.array([0.0, 0.0, 0.4934])  # the paper's simulation study [N m s]
NOISE = 1e-4  # [rad] on angles, [rad/s] on rates
SAMPLES = 35
FIGURES = ("trajectory", "validation", "parameters", "parameters_anchored", "parameters_many", "singular_values",
           "montecarlo", "montecarlo_many", "tracking", "tracking_pd")


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
    many, many_true = _many_parameters()
    plot_parameters(many, paths["parameters_many"], true=many_true)
    plot_montecarlo(_many_parameter_study(), paths["montecarlo_many"])
    plot_singular_values(ident, paths["singular_values"])
    plot_montecarlo(study, paths["montecarlo"])
    for name, feedforward in (("tracking", True), ("tracking_pd", False)):
        with tempfile.TemporaryDirectory() as report:  # the experiment's report draws it
            spaceid.run_experiment(trajectory=traj, seed=0, feedforward=feedforward, out=report)
            shutil.copyfile(Path(report) / "tracking.png", paths[name])
    return paths


def _many_parameter_motion():
    """``(param, model, traj, times, momentum, noise)``: satellite-7dof (153 minimal parameters) on a seeded random
    60 s motion (six harmonics), 3000 samples, momentum 0.1 N m s about x, 1e-5 of noise."""
    from spaceid.motion import FourierTrajectory

    model = spaceid.load_model("satellite-7dof")
    rng = np.random.default_rng(7)
    shape = (model.n_joints, 6)
    traj = FourierTrajectory(model.joints, 60.0, rng.uniform(-0.15, 0.15, shape), rng.uniform(-0.15, 0.15, shape))
    return (spaceid.minimal_parameters(model), model, traj, spaceid.sample_times(60.0, 3000), np.array([0.1, 0.0, 0.0]),
            1e-5)


def _many_parameters():
    """A 153-parameter identification (:func:`_many_parameter_motion`, maximum likelihood) and its truth."""
    param, model, traj, times, momentum, noise = _many_parameter_motion()
    log = spaceid.simulate(param, param.true_values, traj, times, momentum, model=model)
    log = spaceid.add_noise(log, angle=noise, rate=noise, seed=5)
    with warnings.catch_warnings():  # the drift test's false alarm on spatial logs (a known issue)
        warnings.simplefilter("ignore")
        ident = spaceid.identify(param, log, momentum, noise=spaceid.Noise(angle=noise, rate=noise, base_rate=noise))
    return ident, param.true_values


def _many_parameter_study():
    """A Monte Carlo study of the same motion: 10 runs, maximum likelihood and ordinary least squares."""
    param, _, traj, times, momentum, noise = _many_parameter_motion()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return spaceid.run_montecarlo(param, traj, momentum=momentum, times=times, runs=10, estimators=("ml", "ols"),
                                      noise=spaceid.Noise(angle=noise, rate=noise, base_rate=noise), jobs=1)


def _held_out_motion(param, model):
    """A second, different motion to validate on: designed (seed 1, a short search), 101 samples, noisy."""
    traj = spaceid.design_excitation(param, duration=5.0, harmonics=3, samples=SAMPLES, momentum=MOMENTUM, seed=1,
                                     n_starts=4).trajectory
    log = spaceid.simulate(param, param.true_values, traj, spaceid.sample_times(traj.duration, 101), MOMENTUM,
                           model=model)
    return spaceid.add_noise(log, angle=NOISE, rate=NOISE, seed=4)
