"""Each sensor with its own noise, and a gyro bias estimated with the parameters (issue 27, item 2).

The dual-arm servicer preset (src/spaceid/models/presets/servicer-dual.urdf) flies a motion
designed in a short budget (120 s, 12 harmonics, 400 design samples, |qdd| <= 0.3 rad/s^2: the
settings of bench_design_spatial.py; with 8 harmonics its 496 parameters are not all excited),
logged at 50 Hz (6001 samples) with the issue's sensors: encoders 1e-4 rad, joint-rate sensors
1e-4 rad/s, star tracker 5e-5 rad per axis, gyros 1e-5 rad/s per axis and a constant bias of
3e-4 rad/s on each axis (a MEMS-class gyro's). Over ``--runs`` noise seeds it identifies
(``ml`` or ``--estimator``, the noise levels given) three ways: the log without bias (the reference), the biased
log without ``gyro_bias`` (what the warning says) and with it, and prints

- the bias recovered: mean and spread of the estimate against its reported standard error, and
  the attitude's own estimate (``settings.gyro_bias.attitude``);
- the parameter errors over the large parameters (|value| above 1e-3 of the largest in its
  unit): median relative error, RMS z and max |z|, and the fraction within 2 standard errors
  (these measure the identification of this servicer at this design, bias or not); and the
  bias's own effect: how far each biased identification moves the estimates from the reference's
  on the same noise (median and largest |shift| over the reference's standard errors);
- the median wall time of one identification.

Prints only; never fails on the figures.

    python benchmarks/bench_sensors.py [--runs 5] [--budget 60] [--seed 0] [--estimator ml]
"""

import argparse
import statistics
import time
import warnings

import numpy as np

import spaceid
from spaceid.dynamics import minimal_parameters
from spaceid.estimation import Noise, identify
from spaceid.motion import add_noise, design_excitation, sample_times, simulate

MOMENTUM = np.array([2.0, -1.0, 3.0])  # [N m s]
SENSORS = Noise(angle=1e-4, rate=1e-4, base_rate=1e-5, attitude=5e-5)
BIAS = np.array([3e-4, 3e-4, 3e-4])  # [rad/s], base axes
RATE_HZ = 50


def large(param) -> np.ndarray:
    """The parameters whose true value is above 1e-3 of the largest of its unit (the rest are near zero,
    and relative errors mean nothing there)."""
    units = np.array(param.units)
    top = {u: np.abs(param.true_values[units == u]).max() for u in set(units)}
    return np.array([abs(v) > 1e-3 * top[u] for v, u in zip(param.true_values, units)])


def identify_quietly(*args, **kwargs):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        start = time.perf_counter()
        res = identify(*args, **kwargs)
        seconds = time.perf_counter() - start
    return res, seconds, [str(w.message) for w in caught]


def summary(label, param, results, mask):
    true = param.true_values[mask]
    rel = np.array([np.abs(r.values[mask] - true) / np.abs(true) for r in results])
    z = np.array([(r.values[mask] - true) / r.std[mask] for r in results])
    print(f"  {label:<26} median rel. error {100 * np.median(rel):8.3g} %   RMS z {np.sqrt(np.mean(z**2)):8.3g}   "
          f"max |z| {np.abs(z).max():8.3g}   within 2 sigma {100 * np.mean(np.abs(z) < 2):5.1f} %")


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--runs", type=int, default=5, help="noise seeds")
    parser.add_argument("--budget", type=float, default=60.0, help="design time budget [s]")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--estimator", default="ml", choices=("ml", "wls", "ols"))
    args = parser.parse_args()

    model = spaceid.load_model("servicer-dual")
    param = minimal_parameters(model)
    print(f"servicer-dual: {model.mass:.1f} kg, {len(model.joints)} joints, {param.n_params} minimal parameters")
    start = time.perf_counter()
    design = design_excitation(param, duration=120.0, harmonics=12, samples=400, momentum=MOMENTUM, seed=args.seed,
                               qdd_max=0.3, n_starts=2, time_budget=args.budget)
    print(f"design: cond {design.value:.4g} in {time.perf_counter() - start:.0f} s")
    times = sample_times(120.0, 120 * RATE_HZ + 1)
    clean = simulate(param, param.true_values, design.trajectory, times, MOMENTUM, model=model)
    print(f"log: {len(times)} samples at {RATE_HZ} Hz, momentum error {clean.meta['momentum_rel_error']:.1e}; "
          f"base rate RMS {np.sqrt(np.mean(clean.base_w**2)):.3g} rad/s against the bias {BIAS[0]:.0e} rad/s")
    mask = large(param)
    runs = {"no bias (reference)": [], "bias, not estimated": [], "bias, --gyro-bias": []}
    seconds = {k: [] for k in runs}
    biases, stds, attitude, said = [], [], [], set()
    for seed in range(args.runs):
        unbiased = add_noise(clean, noise=SENSORS, seed=seed)
        biased = add_noise(clean, noise=SENSORS, gyro_bias=BIAS, seed=seed)
        for label, log, gyro in (("no bias (reference)", unbiased, False), ("bias, not estimated", biased, False),
                                 ("bias, --gyro-bias", biased, True)):
            res, sec, messages = identify_quietly(param, log, MOMENTUM, noise=SENSORS, gyro_bias=gyro,
                                                  estimator=args.estimator)
            runs[label].append(res)
            seconds[label].append(sec)
            if label == "bias, not estimated":
                said.update(m.split(": ", 1)[1][:160] for m in messages if "gyro bias" in m or "drift" in m)
            if gyro:
                biases.append([d["value"] for d in res.gyro_bias])
                stds.append([d["std"] for d in res.gyro_bias])
                attitude.append(res.settings["gyro_bias"]["attitude"]["value"])
    biases, stds, attitude = np.array(biases), np.array(stds), np.array(attitude)
    print(f"\nbias recovered over {args.runs} seeds (truth {BIAS.tolist()} rad/s):")
    print(f"  mean estimate      {np.round(biases.mean(0), 9).tolist()}")
    spread = biases.std(0, ddof=1) if args.runs > 1 else np.zeros(3)
    print(f"  spread (std)       {np.array2string(spread, precision=3)}")
    print(f"  reported std       {np.array2string(np.median(stds, 0), precision=3)}")
    z = (biases - BIAS) / stds
    print(f"  z of the bias      RMS {np.sqrt(np.mean(z**2)):.3g}, max |z| {np.abs(z).max():.3g}")
    print(f"  attitude alone     mean {np.round(attitude.mean(0), 9).tolist()}")
    print(f"\nparameters ({mask.sum()} large of {param.n_params}):")
    for label, results in runs.items():
        summary(label, param, results, mask)
    for label in ("bias, not estimated", "bias, --gyro-bias"):
        shift = np.array([np.abs(r.values[mask] - ref.values[mask]) / ref.std[mask]
                          for r, ref in zip(runs[label], runs["no bias (reference)"])])
        print(f"  shift from the reference, {label:<20} median {np.median(shift):.3g}, largest {shift.max():.3g} "
              "reference standard errors")
    print("  estimate reported: " + ", ".join(f"{k} {sorted({r.estimator for r in v})}" for k, v in runs.items()))
    chi2 = {k: [r.diagnostics.chi2_dof for r in v if r.diagnostics.chi2_dof is not None] for k, v in runs.items()}
    print("  median chi2/dof: " + ", ".join(f"{k} {statistics.median(v):.3g}" for k, v in chi2.items() if v))
    print("\nwhat the biased log without --gyro-bias says:")
    for text in sorted(said):
        print(f"  {text}")
    print("\nmedian wall time of one identification: " + ", ".join(
        f"{k} {statistics.median(v):.2f} s" for k, v in seconds.items()))


if __name__ == "__main__":
    main()
