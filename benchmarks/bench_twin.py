"""Real-time factor of the Cepheus twin at a 1 kHz control rate with every effect on.

Each run simulates 20 s: the wheel held at 170 rad/s (PI), the arm tracking the paper's
trajectory (PD) and then holding, air-bearing and joint friction, torque limits, thrusters
firing now and then (so the CO2 tank drains and the base inertia is updated), encoders at
50 Hz and motion capture at 100 Hz. One core (threadpoolctl; numpy's small arrays do not
thread anyway). Prints the median of several runs of both wall-clock and process CPU time:
on a shared machine the CPU time is the steadier figure.

    python benchmarks/bench_twin.py [--runs 5] [--duration 20]
"""

import argparse
import os
import statistics
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

from threadpoolctl import threadpool_limits  # noqa: E402

from spaceid.motion import load_trajectory  # noqa: E402
from spaceid.twin import Controllers, Tank, Thrusters, TwinSettings, TwinState, run_twin  # noqa: E402


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--duration", type=float, default=20.0)
    args = parser.parse_args()

    schedule = tuple((t, t + 0.3, k % 3, 1 if k % 2 else -1) for k, t in enumerate(range(1, int(args.duration), 4)))
    settings = TwinSettings(thrusters=Thrusters(schedule=schedule), tank=Tank(bearing_flow=5e-5))
    # start as after a spin-up: wheel at 170 rad/s relative to the base, PI integral settled
    state = TwinState(qd=[170.0, 0.0, 0.0], base_wz=-1.39, command=[170.0, 0.0, 0.0])
    traj = load_trajectory("paper-table2")
    steps = int(round(args.duration * settings.controllers.rate))

    with threadpool_limits(1):
        run_twin(traj, duration=0.2, settings=settings, state=state)  # warm-up (imports, YAML)
        wall, cpu = [], []
        for seed in range(args.runs):
            w0, c0 = time.perf_counter(), time.process_time()
            run = run_twin(traj, duration=args.duration, settings=settings, state=state, seed=seed)
            cpu.append(time.process_time() - c0)
            wall.append(time.perf_counter() - w0)
        ff = TwinSettings(thrusters=settings.thrusters, tank=settings.tank, controllers=Controllers(feedforward=True))
        c0 = time.process_time()
        run_ff = run_twin(traj, duration=args.duration, settings=ff, state=state, seed=0)
        cpu_ff = time.process_time() - c0

    m = run.meta
    print(f"twin, {args.duration:g} s simulated at {settings.controllers.rate:g} Hz ({steps} RK4 steps), all effects on")
    print(f"  thruster firings {len(schedule)}, CO2 {m['co2_mass_start']:.4f} -> {m['co2_mass_end']:.4f} kg, "
          f"joint states {len(run.recording.joints.t)}, mocap frames {len(run.recording.base.t)} "
          f"({m['mocap_dropped']} dropped)")
    print(f"  wall time   median {statistics.median(wall):.3f} s over {args.runs} runs "
          f"(min {min(wall):.3f}, max {max(wall):.3f}): real-time factor {args.duration / statistics.median(wall):.1f}x")
    print(f"  CPU time    median {statistics.median(cpu):.3f} s: real-time factor {args.duration / statistics.median(cpu):.1f}x, "
          f"{statistics.median(cpu) / steps * 1e6:.1f} us per step")
    print(f"  with inverse-dynamics feed-forward: CPU {cpu_ff:.3f} s, real-time factor {args.duration / cpu_ff:.1f}x")
    rms = m["tracking_rms"]
    rms_ff = run_ff.meta["tracking_rms"]
    print("  tracking RMS over the run (true angle - set point) [rad]: "
          + ", ".join(f"{j} {rms[j]:.4f} (feed-forward {rms_ff[j]:.4f})" for j in rms))
    print("  target: at least 20x real time on one core")


if __name__ == "__main__":
    main()
