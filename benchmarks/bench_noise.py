"""Identification under measurement noise on Cepheus: the Monte Carlo targets of issue 4.

Cepheus, tf = 5 s, h = 0.4934 N m s, noise 1e-4 rad on the joint angles (and the base
attitude), 1e-4 rad/s on the joint rates and the base rate, 500 runs per study
(``spaceid.montecarlo.run_montecarlo``, every estimator):

(a) the paper's Table 2 trajectory at the demo's sampling (N = 35): per parameter RMSE / CRB
    (target <= 1.2 with the default estimator, ml) and |bias| / std (target < 0.2);
(b) spaceid's designed trajectory, N = 35, ``design_excitation`` with the demo's settings (3
    harmonics, seed 0, 32 starts), criterion ``cond`` and, when ``design.CRITERIA`` has it,
    the noise-aware ``crb``: worst relative RMSE over the parameters (target <= 0.25 %; the
    paper's worst Table 3 error is 1.30 %);
(c) angles only: noise on the joint angles and the base yaw, rates differentiated
    (Savitzky-Golay, automatic window) at 100 Hz (N = 501), on the ``cond`` design; the CRB
    there is the white-noise equivalent of the differentiated signals (a yardstick, not a
    bound), and the bound with measured rates at 100 Hz is printed beside it. The ``angles``
    estimator (maximum likelihood on the joint angles and yaw, no rates) runs with the others;
    then every estimator against the bound that applies here, the Cramer-Rao bound for angle
    measurements (``cramer_rao_angles``; spline knots every 0.05 s, and at 0.1 s and 0.025 s to
    show it does not depend on them): RMSE / bound (target <= 1.5 for ``angles``) and
    predicted / actual std.

(s) spatial, angles only: encoders (1e-4 rad) and a star tracker (5e-5 rad per axis), no rates, the
    ``angles`` estimator (the attitude propagated on the rotation group), Monte Carlo over noise
    seeds against ``cramer_rao_angles``: a random spatial tree (5 s at 100 Hz), and the satellite-7dof
    preset (153 parameters) on a designed motion (``design_excitation``: 30 s, 6 harmonics, seed 0,
    4 starts of 20 steps, |qdd| <= 0.5; sampled at 20 Hz, knots every 0.1 s) at these levels and at
    a tenth and a hundredth of them, and on an undesigned one (10 s at 50 Hz, six random harmonics per joint, seed 1);
    the issue's servicer (``servicer-7dof.urdf``) on the designed 120 s of ``bench_servicer.py`` at 50 Hz, knots
    chosen by ``identify``: the bound relative to the large parameters (median), RMSE / bound (target <= 1.5),
    actual / reported std (target within 20 %), over every parameter and the large ones
    (``spaceid.studies.large_parameters``), the fits whose likelihood did not converge (reported: ML on the
    differentiated rates, with a warning), the CPU time of one fit; and the same figures for ``ml`` on rates
    differentiated from the same angles. ``--jobs`` processes run the draws.

Then the median wall time of one identification per estimator (N = 35 and N = 501) and of one
differentiation at 100 Hz. Prints only; never fails on the figures.

    python benchmarks/bench_noise.py [--runs 500] [--jobs N] [--seed 0] [--parts a b c s] [--spatial-runs 30]
                                     [--spatial-cases tree servicer-designed ...]
"""

import argparse
import os
import statistics
import time

import numpy as np

import spaceid
from spaceid.motion import _design as design
from spaceid.studies import CEPHEUS_STUDY
from spaceid.estimation import ESTIMATORS, KNOT_SPACING, cramer_rao, cramer_rao_angles, identify
from spaceid.estimation.internal import automatic_knot_spacing
from spaceid.studies import DEFAULT_NOISE, run_montecarlo
from spaceid.dynamics import minimal_parameters
from spaceid.data import differentiate_log
from spaceid.motion import add_noise, simulate
from spaceid.motion import load_trajectory, sample_times

MOMENTUM = np.array([0.0, 0.0, CEPHEUS_STUDY["momentum"]])  # [N m s]
NOISE = DEFAULT_NOISE  # 1e-4 rad on angles and attitude, 1e-4 rad/s on joint and base rates
ESTIMATOR_ORDER = ("ml",) + tuple(e for e in ESTIMATORS if e != "ml")
RATE_ESTIMATORS = tuple(e for e in ESTIMATOR_ORDER if e != "angles")  # "angles" needs >= 40 Hz: part (c) only
RATE_HZ = 100
SPATIAL_CASES = ("tree", "satellite-designed", "satellite-designed-tenth", "satellite-designed-hundredth",
                 "satellite-random", "servicer-designed")


def line(label, values, fmt, worst=np.nanmax):
    """One table row: a label, a value per parameter and the worst of them."""
    print(f"{label:<16}" + "".join(f"{v:{fmt}}" for v in values) + f"{worst(values):{fmt}}")


def table(res, extra_crb=None):
    """Parameters as columns: the relative CRB, then per estimator RMSE [%], RMSE / CRB and
    bias / std; the last column is the worst over the parameters."""
    rel_crb = 100 * res.crb_std / np.abs(res.true)
    head = "".join(f"{n:>8}" for n in res.names)
    print(f"{'':<16}{head}{'worst':>8}")

    crb_label = "CRB* [%]" if res.settings["angles_only"] else "CRB [%]"
    line(crb_label, rel_crb, "8.4f")
    if extra_crb is not None:
        line("CRB rates [%]", extra_crb, "8.4f")
    for e in res.estimators:
        s = res.stats[e]
        line(f"{e.upper()} RMSE [%]", 100 * s["relative_rmse"], "8.4f")
        line(f"{e.upper()} RMSE/CRB", s["rmse_crb"], "8.3f")
        line(f"{e.upper()} bias/std", s["bias_std"], "+8.3f", worst=lambda v: np.nanmax(np.abs(v)))
    failed = res.settings["failures"]["count"]
    warned = res.settings["warnings"]["count"]
    if failed or warned:
        print(f"  failures: {res.settings['failures']['reasons']}; warnings: {res.settings['warnings']['messages']}")


def study(label, param, traj, args, *, samples, angles_only=False, extra_crb=None, estimators=RATE_ESTIMATORS):
    t0 = time.perf_counter()
    res = run_montecarlo(param, traj, momentum=MOMENTUM, noise=NOISE, samples=samples, runs=args.runs,
                         estimators=estimators, seed=args.seed, jobs=args.jobs, angles_only=angles_only)
    wall = time.perf_counter() - t0
    print(f"\n{label}: N = {samples}, {args.runs} runs, seed {args.seed}, {res.settings['jobs']} jobs, "
          f"wall {wall:.1f} s")
    table(res, extra_crb)
    return res


def farthest_from_one(ratios):
    return ratios[np.nanargmax(np.abs(np.log(ratios)))]


def angle_bound(res, param, clean):
    """Every estimator of study ``res`` against the Cramer-Rao bound for angle measurements of the
    noise-free log ``clean``: the bound at three knot spacings, RMSE / bound, predicted / actual std."""
    bounds = {}
    for spacing in (0.1, KNOT_SPACING, 0.025):
        t0 = time.perf_counter()
        bounds[spacing] = np.sqrt(np.diag(cramer_rao_angles(param, clean, MOMENTUM, NOISE, knot_spacing=spacing)[1]))
        print(f"  bound for angle measurements, knots every {spacing} s: worst relative "
              f"{100 * np.max(bounds[spacing] / np.abs(res.true)):.4f} %, largest change from {KNOT_SPACING} s "
              f"{np.max(np.abs(bounds[spacing] / bounds.get(KNOT_SPACING, bounds[spacing]) - 1)):.1e} "
              f"({time.perf_counter() - t0:.1f} s)")
    bound = bounds[KNOT_SPACING]
    print(f"{'':<16}" + "".join(f"{n:>8}" for n in res.names) + f"{'worst':>8}")
    line("CRB angles [%]", 100 * bound / np.abs(res.true), "8.4f")
    for e in res.estimators:
        s = res.stats[e]
        line(f"{e.upper()} RMSE/CRBa", s["rmse"] / bound, "8.3f")
        line(f"{e.upper()} pred/act", s["predicted_std"] / s["std"], "8.3f", worst=farthest_from_one)
    if "angles" in res.estimators:
        w = np.max(res.stats["angles"]["rmse"] / bound)
        verdict(f"angles: max RMSE / angle bound <= 1.5 (knots every {KNOT_SPACING} s)", f"{w:.3f}", w <= 1.5)


def verdict(text, value, ok):
    print(f"  {text}: {value} -> {'met' if ok else 'NOT met'}")


def designed(param, criterion):
    t0 = time.perf_counter()
    res = design.design_excitation(param, duration=CEPHEUS_STUDY["duration"], harmonics=CEPHEUS_STUDY["harmonics"],
                            samples=CEPHEUS_STUDY["samples"], momentum=MOMENTUM, seed=0, criterion=criterion,
                            noise=NOISE, n_starts=32)  # fmt: skip
    wall = time.perf_counter() - t0
    traj = res.trajectory
    rel = [v for v in traj.meta.get("crb_relative_std", {}).values() if v is not None]
    print(f"\ndesign '{criterion}' (seed 0, 32 starts): {criterion} = {res.value:.4g}, predicted worst relative "
          f"CRB std {100 * max(rel):.4f} %, wall {wall:.1f} s")
    return traj


def timings(param, traj):
    """Median wall times of one identification per estimator and of one differentiation."""
    motion = lambda t: traj.evaluate(t)[:2]  # noqa: E731
    print("\nmedian wall time of one call [ms] (identify with the noise given; 15 calls, differentiation 5)")
    for n in (CEPHEUS_STUDY["samples"], RATE_HZ * 5 + 1):
        clean = simulate(param, param.true_values, motion, sample_times(5.0, n), MOMENTUM)
        log = add_noise(clean, angle=1e-4, rate=1e-4, seed=1)
        cells = []
        for e in ESTIMATOR_ORDER if n > CEPHEUS_STUDY["samples"] else RATE_ESTIMATORS:
            times = []
            for _ in range(15):
                t0 = time.perf_counter()
                identify(param, log, MOMENTUM, estimator=e, noise=NOISE)
                times.append(time.perf_counter() - t0)
            cells.append(f"{e} {1e3 * statistics.median(times):.1f}")
        print(f"  N = {n}: " + ", ".join(cells))
    times = []
    for seed in range(5):
        log = add_noise(clean, angle=1e-4, rate=0.0, seed=seed)
        t0 = time.perf_counter()
        differentiate_log(log)
        times.append(time.perf_counter() - t0)
    print(f"  differentiate_log at {RATE_HZ} Hz (N = {clean.n_samples}): {1e3 * statistics.median(times):.0f}")


def spatial_motion(nj, seed, count, speed=3.0):
    """A smooth random joint motion: ``count`` harmonics per joint (amplitude 0.6 rad in total at most)."""
    rng = np.random.default_rng(seed)
    a, w = rng.uniform(0.2, 0.6, (count, nj)) * 3 / count, rng.uniform(0.5, speed, (count, nj))
    p = rng.uniform(0, 6, (count, nj))

    def motion(s):
        s = np.asarray(s, float)[..., None, None]
        return (a * np.sin(w * s + p)).sum(-2), (a * w * np.cos(w * s + p)).sum(-2)

    return motion


def _spatial_draw(param, clean, h, noise, knot_spacing, seed):
    """One noise draw of part (s): the ``angles`` fit and ``ml`` on rates differentiated from the same angles, each
    as ``(values, std, CPU seconds, note)`` (values None when it failed; note the fallback or failure)."""
    import warnings
    from dataclasses import replace

    joints, base = add_noise(clean, angle=noise.angle, seed=2 * seed), add_noise(clean, angle=noise.attitude,
                                                                                   seed=2 * seed + 1)  # fmt: skip
    log = replace(joints, base_quat=base.base_quat, qd=np.zeros_like(joints.qd), base_w=np.zeros_like(joints.base_w))
    out = {}
    for estimator in ("angles", "ml"):
        t0 = time.process_time()
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                ident = (identify(param, log, h, estimator="angles", noise=noise, knot_spacing=knot_spacing)
                         if estimator == "angles" else identify(param, differentiate_log(log), h, estimator="ml"))
        except spaceid.SpaceidError as exc:  # counted and shown: the figures are over the runs that ended
            out[estimator] = (None, None, time.process_time() - t0, f"seed {seed}: {str(exc)[:120]}")
            continue
        note = ident.diagnostics.estimator_info.get("fallback")  # not the likelihood's estimate: counted apart
        out[estimator] = (ident.values, ident.std, time.process_time() - t0, note and f"seed {seed}: {note[:110]}")
    print(f"    seed {seed}: " + ", ".join(f"{e} {o[2]:.0f} s CPU{' (' + o[3] + ')' if o[3] else ''}"
                                        for e, o in out.items()), flush=True)
    return out


def spatial_study(label, param, motion, t, runs, scale=1.0, knot_spacing=KNOT_SPACING, h=(0.3, -0.2, 0.5),
                  initial_quat=(0.9, 0.1, 0.3, -0.2), jobs=None):
    """Monte Carlo of the angles estimator on a spatial model: encoder and star-tracker noise (1e-4 and
    5e-5 rad, times ``scale``), momentum ``h`` [N m s]; beside it ``ml`` on rates differentiated from the same
    angles, the draws in ``jobs`` processes. Figures over every parameter and over the large ones
    (``spaceid.studies.large_parameters``); ``knot_spacing`` None: identify's choice."""
    from spaceid.estimation import Noise
    from spaceid.studies import large_parameters

    h = np.asarray(h, float)
    noise = Noise(angle=1e-4 * scale, attitude=5e-5 * scale)
    clean = simulate(param, param.true_values, motion, t, h, initial_quat=list(initial_quat))
    chosen, given = "given", knot_spacing  # the fits' (None: identify chooses, draw by draw)
    if knot_spacing is None:  # identify's choice (the same on every draw here): the bound's knots too
        knot_spacing = automatic_knot_spacing(t, add_noise(clean, angle=noise.angle, seed=0).q, noise.angle)
        chosen = "identify's automatic choice"
    t0 = time.process_time()
    bound = np.sqrt(np.diag(cramer_rao_angles(param, clean, h, noise, knot_spacing=knot_spacing)[1]))
    cpu_bound = time.process_time() - t0
    large = large_parameters(param, clean, param.true_values)
    relative = bound[large] / np.abs(param.true_values[large])
    print(f"\n{label}, noise {noise.angle:g} rad (encoders), {noise.attitude:g} rad (star tracker), knots every "
          f"{knot_spacing:g} s ({chosen}): bound / |value| over the {len(large)} large parameters: median "
          f"{np.median(relative):.3g}, largest {relative.max():.3g}")
    if chosen != "given":  # coarse knots lose nothing: the bound with knots twice as dense
        finer = np.sqrt(np.diag(cramer_rao_angles(param, clean, h, noise, knot_spacing=knot_spacing / 2)[1]))
        print(f"  bound with knots every {knot_spacing / 2:g} s: largest change {np.max(np.abs(finer / bound - 1)):.1e}")
    from concurrent.futures import ProcessPoolExecutor
    from functools import partial

    with ProcessPoolExecutor(jobs) as pool:  # one noise draw per task
        draws = list(pool.map(partial(_spatial_draw, param, clean, h, noise, given), range(runs)))
    print(f"  {param.n_params} parameters ({len(large)} large), {len(t)} samples, {runs} noise seeds; bound "
          f"{cpu_bound:.1f} s CPU")
    for estimator in ("angles", "ml"):
        _spatial_figures(estimator, [d[estimator] for d in draws], param.true_values, bound, large, runs)


def _spatial_figures(estimator, fits, truth, bound, large, runs):
    """The figures of part (s) for one estimator's ``fits`` (:func:`_spatial_draw`) against the angle bound."""
    failed = [f[3] for f in fits if f[0] is None]
    fallbacks = [f[3] for f in fits if f[0] is not None and f[3]]
    kept = [f for f in fits if f[0] is not None and not f[3]]
    cpu = statistics.median(f[2] for f in fits)
    print(f"  {estimator}: {len(kept)} of {runs} converged, one fit median {cpu:.1f} s CPU")
    if fallbacks:
        print(f"    NOT CONVERGED {len(fallbacks)} of {runs}: " + "; ".join(fallbacks[:2]))
    if failed:
        print(f"    FAILED {len(failed)} of {runs}: " + "; ".join(failed[:3]))
    if len(kept) < 2:
        print(f"    {len(kept)} converged fits: too few for the figures")
        return
    est, std = np.array([f[0] for f in kept]), np.array([f[1] for f in kept])
    rmse = np.sqrt(np.mean((est - truth) ** 2, 0)) / bound
    spread = est.std(0, ddof=1) / std.mean(0)
    z = (est - truth) / std
    for name, sel in (("all", slice(None)), ("large", large)):
        print(f"    {name:>5}: RMSE / bound median {np.median(rmse[sel]):.3f} (range {rmse[sel].min():.3f} .. "
              f"{rmse[sel].max():.3f}); actual / reported std median {np.median(spread[sel]):.3f} (range "
              f"{spread[sel].min():.3f} .. {spread[sel].max():.3f}); |z| max {np.abs(z[:, sel]).max():.2f}, RMS z "
              f"{np.sqrt(np.mean(z[:, sel] ** 2)):.3f}")
    if estimator == "angles":
        ok = not failed and not fallbacks
        verdict("max RMSE / bound <= 1.5 (large parameters)", f"{rmse[large].max():.3f}", rmse[large].max() <= 1.5 and ok)
        worst = farthest_from_one(spread[large])
        verdict("actual / reported std within 20 % (large parameters)", f"{worst:.3f}", abs(worst - 1) <= 0.2 and ok)


def spatial(runs, cases, jobs=None):
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parents[1] / "tests"))
    from conftest import random_tree

    if "tree" in cases:
        tree = minimal_parameters(random_tree(np.random.default_rng(7), [0, 1], planar=False))
        spatial_study("(s) random spatial tree (3 bodies), 5 s at 100 Hz", tree, spatial_motion(2, 1, 3),
                      np.linspace(0, 5, 501), runs, jobs=jobs)  # fmt: skip
    sat = minimal_parameters(spaceid.load_model("satellite-7dof"))
    if any(c.startswith("satellite-designed") for c in cases):
        t0 = time.perf_counter()
        res = design.design_excitation(sat, duration=30.0, harmonics=6, samples=120, momentum=np.array([0.3, -0.2, 0.5]),
                                       seed=0, qdd_max=0.5, n_starts=4, max_steps=20)  # fmt: skip
        print(f"\nsatellite-7dof design (30 s, 6 harmonics, seed 0, 4 starts x 20 steps): cond {res.value:.4g}, "
              f"wall {time.perf_counter() - t0:.0f} s")
        motion = lambda s: res.trajectory.evaluate(s)[:2]  # noqa: E731
        for case, scale in (("satellite-designed", 1.0), ("satellite-designed-tenth", 0.1),
                            ("satellite-designed-hundredth", 0.01)):
            if case in cases:
                spatial_study("(s) satellite-7dof, designed, 30 s at 20 Hz", sat, motion, np.linspace(0, 30, 601), runs,
                              scale, knot_spacing=0.1, jobs=jobs)  # fmt: skip
    if "servicer-designed" in cases:
        servicer_study(runs, jobs)
    if "satellite-random" in cases:
        spatial_study("(s) satellite-7dof, undesigned, 10 s at 50 Hz", sat, spatial_motion(7, 1, 6),
                      np.linspace(0, 10, 501), runs, jobs=jobs)  # fmt: skip


def servicer_study(runs, jobs=None, budget=90.0, seed=0):
    """Part (s) on the issue's servicer (``benchmarks/servicer-7dof.urdf``, 153 parameters) at the real sensor
    levels, on the designed 120 s of ``bench_servicer.py`` (the same cached design: ``crb``, 8 harmonics,
    |qdd| <= 0.3, ``budget`` s) flown in spaceid's own simulation (the truth known exactly) and sampled at
    50 Hz. The knots are identify's default for a spatial log (``automatic_knot_spacing``; docs/theory/angles.md,
    "Knots")."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    import bench_servicer as servicer

    model = spaceid.load_model(servicer.URDF)
    param = minimal_parameters(model)
    nj = len(model.joints)
    h = spaceid.dynamics.angular_momentum(model, np.zeros(nj), np.zeros(nj), np.asarray(servicer.BASE_W))
    work = Path("/tmp/spaceid-bench-servicer-7dof")
    work.mkdir(parents=True, exist_ok=True)
    traj = servicer._designed(param, h, budget, seed, work)
    motion = lambda s: traj.evaluate(s)[:2]  # noqa: E731
    spatial_study(f"(s) servicer-7dof, designed (bench_servicer.py, seed {seed}, budget {budget:g} s), 120 s at "
                  "50 Hz", param, motion, servicer._times(120.0), runs, knot_spacing=None, h=h, jobs=jobs)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=500)
    parser.add_argument("--jobs", type=int, help="worker processes (default: all cores)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--parts", nargs="+", default=["a", "b", "c", "s"], choices=["a", "b", "c", "s"])
    parser.add_argument("--spatial-runs", type=int, default=30, help="noise seeds of part (s)")
    parser.add_argument("--spatial-cases", nargs="+", default=list(SPATIAL_CASES), choices=SPATIAL_CASES,
                        help="the systems of part (s)")
    args = parser.parse_args()
    t_all = time.perf_counter()
    param = minimal_parameters(spaceid.load_model("cepheus"))
    print(f"Cepheus: tf = 5 s, h = {MOMENTUM[2]} N m s, noise {NOISE.angle:g} rad (angles, attitude), "
          f"{NOISE.rate:g} rad/s (joint rates), {NOISE.base_rate:g} rad/s (base rate); {os.cpu_count()} cores")
    print("CRB: relative Cramer-Rao std; RMSE/CRB: 1 is efficient; bias/std: bias in units of the spread")

    if "a" in args.parts:
        res = study("(a) paper-table2 at the demo's sampling", param, load_trajectory("paper-table2"), args,
                    samples=CEPHEUS_STUDY["samples"])  # fmt: skip
        w = res.summary("ml")
        print("targets (ml):")
        verdict("max RMSE/CRB <= 1.2", f"{w['rmse_crb']:.3f}", w["rmse_crb"] <= 1.2)
        verdict("max |bias|/std < 0.2", f"{w['abs_bias_std']:.3f}", w["abs_bias_std"] < 0.2)

    design_traj = None
    if "b" in args.parts or "c" in args.parts:
        criteria = [c for c in ("cond", "crb") if c in design.CRITERIA]
        if "b" not in args.parts:
            criteria = ["cond"]
        for criterion in criteria:
            traj = designed(param, criterion)
            design_traj = design_traj or traj
            if "b" in args.parts:
                res = study(f"(b) designed ({criterion})", param, traj, args, samples=CEPHEUS_STUDY["samples"])
                print("target (ml; paper's worst Table 3 error 1.30 %):")
                w = res.summary("ml")
                verdict("worst relative RMSE <= 0.25 %", f"{100 * w['relative_rmse']:.4f} %",
                        w["relative_rmse"] <= 0.0025)  # fmt: skip
                others = ", ".join(f"{e} {100 * res.summary(e)['relative_rmse']:.4f} %" for e in res.estimators[1:])
                print(f"  others: {others}")

    if "c" in args.parts:
        n = RATE_HZ * 5 + 1
        motion = lambda t: design_traj.evaluate(t)[:2]  # noqa: E731
        clean = simulate(param, param.true_values, motion, sample_times(5.0, n), MOMENTUM)
        _, cov = cramer_rao(param, clean, MOMENTUM, NOISE)
        rates_crb = 100 * np.sqrt(np.diag(cov)) / np.abs(param.true_values)
        res = study(f"(c) angles only, rates differentiated at {RATE_HZ} Hz, designed (cond)", param, design_traj,
                    args, samples=n, angles_only=True, extra_crb=rates_crb, estimators=ESTIMATOR_ORDER)  # fmt: skip
        d = res.settings["differentiation"]
        print(f"  differentiator: {d['method']}; windows and orders chosen (joints | base: runs):")
        for c in d["choices"][:6]:
            print(f"    {c['joints'].get('window')} {c['joints'].get('order')} | {c['base'].get('window')} "
                  f"{c['base'].get('order')}: {c['runs']}")
        print("  white-noise equivalent levels (RMS over runs): "
              + ", ".join(f"{k} {v:.3g}" for k, v in d["noise_equivalent_rms"].items() if k != "source"))
        for e in res.estimators:
            w = res.summary(e)
            print(f"  {e}: worst relative RMSE {100 * w['relative_rmse']:.4f} %, worst |bias|/std "
                  f"{w['abs_bias_std']:.3f}, predicted/actual std median "
                  f"{np.nanmedian(res.stats[e]['predicted_std'] / res.stats[e]['std']):.2f}")
        angle_bound(res, param, clean)

    if "s" in args.parts:
        spatial(args.spatial_runs, args.spatial_cases, args.jobs)
        if args.parts == ["s"]:
            return
    timings(param, design_traj or load_trajectory("paper-table2"))
    print(f"\ntotal wall time {time.perf_counter() - t_all:.0f} s")


if __name__ == "__main__":
    main()
