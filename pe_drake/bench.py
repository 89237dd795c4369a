"""Benchmarks that print numbers: ``python -m pe_drake.bench NAME`` (gradient, identify, diagnose,
sensitivity, solve, payload, memory, robots).

Each prints its measurements and ends with one line ``BENCH key=value ...`` for scripts.
Timings are wall-clock medians of repeated runs (``solve``: CPU seconds of single runs).
"""

from __future__ import annotations

import argparse
import importlib
import math
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from pe_drake.config import ExcitationConfig
from pe_drake.diagnosis import diagnose
from pe_drake.excitation.fourier import FourierTrajectory
from pe_drake.excitation.problem import ExcitationProblem
from pe_drake.excitation.trajectory_file import load_trajectory
from pe_drake.identification.estimators import identify
from pe_drake.identification.intake import prepare_measurement, read_robot_measurement
from pe_drake.identification.measurements import write_measurement_csv
from pe_drake.memory import reuse_freed_memory
from pe_drake.multibody.robot import load_robot
from pe_drake.simulation.simulation import simulate
from pe_drake.simulation.synthetic import model_measurement
from pe_drake.simulation.truth import ControlTruth, NoiseTruth, make_truth
from pe_drake.threads import single_threaded_blas

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

#: Benchmark name -> its module; each module's ``bench_<name>(args)`` prints its results.
_BENCHMARKS = {name: "pe_drake.bench" for name in ("gradient", "identify", "diagnose",
                                                   "sensitivity")}
_BENCHMARKS |= {name: f"pe_drake.bench_{name}" for name in ("solve", "payload", "memory", "robots")}


def median_time(function: Callable[[], object], repeats: int = 7, warmup: int = 1,
                warmup_seconds: float = 1.0) -> float:
    """Median wall time of ``function()`` over ``repeats`` runs [s], in steady state: after
    ``warmup`` runs lasting at least ``warmup_seconds`` (cold caches, a CPU not yet at its clock).
    """
    start = time.perf_counter()
    done = 0
    while done < warmup or time.perf_counter() - start < warmup_seconds:
        function()
        done += 1
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def cpu_time_per_call(function: Callable[[], object], calls: int) -> float:
    """CPU seconds of one ``function()`` over ``calls`` calls after a warm-up (on a loaded
    machine less disturbed than a wall-clock median)."""
    for _ in range(max(10, calls // 10)):
        function()
    start = time.process_time()
    for _ in range(calls):
        function()
    return (time.process_time() - start) / calls


def bench_gradient(args: argparse.Namespace) -> None:
    """Times the cost, its analytic gradient and a finite-difference one at the paper's size
    (G1's 14 arm joints, N = 10, ω = π/4, T = 40), as the solvers run (one BLAS thread, freed
    memory reused unless ``--default-malloc``)."""
    reused = False if args.default_malloc else reuse_freed_memory()

    robot = load_robot(args.robot)
    # The paper's criterion and its Eq. (17) gradient, as in its timing.
    config = ExcitationConfig(harmonics=10, omega=math.pi / 4, cost_samples=40, criterion="cond",
                              drive_terms=args.drive_terms)
    problem = ExcitationProblem(robot, config)
    rng = np.random.default_rng(args.seed)
    alpha = problem.initial_guess(seed=args.seed, amplitude=0.3)
    alpha += 1e-9 * rng.normal(size=alpha.shape)
    with single_threaded_blas():
        cost_s = median_time(lambda: problem.value(alpha), repeats=args.repeats)

        def analytic():
            problem.clear_cache()  # no caching: value + gradient from scratch
            return problem.evaluate(alpha).grad

        grad_s = median_time(analytic, repeats=args.repeats)
        grad_cpu_s = cpu_time_per_call(analytic, 20 * args.repeats)
        grad = analytic()
        steps = 1e-6 * np.maximum(1.0, np.abs(alpha))
        units = np.eye(len(alpha))

        def forward_difference():
            f0 = problem.value(alpha)
            return [(problem.value(alpha + s * e) - f0) / s for s, e in zip(steps, units)]

        fd_s = median_time(forward_difference, repeats=1, warmup=0, warmup_seconds=0.0)
        # Accuracy against central differences (forward ones carry O(h) error).
        central = np.array([(problem.value(alpha + s * e) - problem.value(alpha - s * e)) / (2 * s)
                            for s, e in zip(steps, units)])
    rel_err = float(np.linalg.norm(grad - central) / np.linalg.norm(central))
    print(f"robot {robot.name}: n = {robot.n}, N = 10, T = 40, variables = {problem.num_variables}, "
          f"base parameters = {problem.base.count}, drive terms = {problem.drive.count} ({args.drive_terms}), "
          f"cond = {problem.value(alpha):.4g}; "
          f"freed memory {'reused' if reused else 'returned (glibc defaults)'}")
    print(f"one cost evaluation            {cost_s * 1e3:9.2f} ms")
    print(f"one analytic gradient          {grad_s * 1e3:9.2f} ms  (value + gradient, = {grad_s / cost_s:.2f} cost evaluations)")
    print(f"one analytic gradient, CPU     {grad_cpu_s * 1e3:9.2f} ms  (process time over {20 * args.repeats} calls)")
    print(f"one forward-difference gradient {fd_s * 1e3:8.1f} ms  ({problem.num_variables + 1} cost evaluations)")
    print(f"speed-up fd / analytic         {fd_s / grad_s:9.1f} x   (paper: 89 x)")
    print(f"relative error vs central differences {rel_err:.2e}   (paper: 1.3e-5)")
    print(f"BENCH cost_ms={cost_s * 1e3:.3f} grad_ms={grad_s * 1e3:.3f} grad_cpu_ms={grad_cpu_s * 1e3:.3f} fd_ms={fd_s * 1e3:.1f} rel_err={rel_err:.3e}")



def bench_identify(args: argparse.Namespace) -> None:
    """Times the identification of 20 s of 1 kHz data of a 7-dof arm (CSV to estimate)."""
    robot = load_robot(args.robot)
    trajectory_file = Path(__file__).resolve().parent.parent / "tests" / "data" / "panda_optimized.json"
    if robot.name == "panda" and trajectory_file.is_file():
        trajectory, _ = load_trajectory(trajectory_file)
    else:
        problem = ExcitationProblem(robot)
        trajectory = problem.trajectory(problem.initial_guess(seed=args.seed))
    sim = model_measurement(robot, trajectory, rate_hz=1000.0, duration=20.0, tau_noise_std=0.05,
                            seed=args.seed)
    raw_rows = sim.num_samples
    sim = sim.replace(v=None, vd=None)  # a user's CSV has only q and tau
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "data.csv"
        write_measurement_csv(path, sim)
        print(f"robot {robot.name}: {robot.n} joints; {raw_rows} samples (20 s at 1 kHz), q and tau only")
        for method in ("ols", "wls", "physical"):
            times = []
            for _ in range(max(1, min(args.repeats, 3))):
                t0 = time.perf_counter()
                raw = read_robot_measurement(robot, path)
                t1 = time.perf_counter()
                data = prepare_measurement(robot, raw)
                t2 = time.perf_counter()
                result = identify(robot, data, method)
                t3 = time.perf_counter()
                times.append((t3 - t0, t1 - t0, t2 - t1, t3 - t2))
            total, read, prep, est = np.median(np.array(times), axis=0)
            print(f"{method:9s} total {total:6.2f} s (read {read:.2f}, preprocess {prep:.2f}, "
                  f"regressor + estimate {est:.2f}); {result.samples} samples, "
                  f"cond(W) {result.cond:.4g}")
            print(f"BENCH identify_{method}_s={total:.3f}")
    print("target: OLS under 5 s on 2 cores")


def bench_trajectory(robot: Robot, seed: int, harmonics: int = 5, period: float = 10.0):
    """A random Fourier trajectory about the nominal posture, as large as the joint limits and
    self-collision (capsule distance ≥ 2 cm: the simulated robot collides) allow."""
    rng = np.random.default_rng(seed)
    n = robot.n
    a, b = rng.uniform(-1, 1, (2, n, harmonics)) / harmonics
    q0 = robot.nominal_posture()
    half = 0.5 * (robot.limits.q_upper - robot.limits.q_lower)
    t = np.linspace(0.0, period, 400, endpoint=False)
    scale = 1.0
    for _ in range(30):
        trajectory = FourierTrajectory(a * scale, b * scale, q0, 2 * math.pi / period)
        q, _, _ = trajectory.evaluate(t)
        inside = np.all((q > robot.limits.q_lower) & (q < robot.limits.q_upper))
        if inside and np.all(np.abs(q - q0).max(axis=0) <= 0.8 * half) and _capsule_clearance(robot, q) >= 0.02:
            return trajectory
        scale *= 0.85
    return trajectory


def _capsule_clearance(robot: Robot, q: np.ndarray) -> float:
    """Smallest distance between the robot's collision capsules over configurations [m]."""
    if not getattr(robot, "capsules", ()):
        return math.inf
    plant, sg = robot.plant, robot.scene_graph
    sg_ctx = sg.GetMyContextFromRoot(robot.context)
    best = math.inf
    for qk in q:
        plant.SetPositions(robot.plant_context, qk)
        query = sg.get_query_output_port().Eval(sg_ctx)
        for pair in query.ComputeSignedDistancePairwiseClosestPoints(0.05):
            best = min(best, pair.distance)
    return best


def bench_diagnose(args) -> None:
    """Times the diagnosis, outputs included, of 20 s of simulated 1 kHz data on a 7-dof arm
    (Coulomb + viscous friction, 3 % inertial error, noise, a random trajectory)."""
    robot = load_robot(args.robot)
    trajectory = bench_trajectory(robot, args.seed)
    n = robot.n
    truth = make_truth(robot, {"viscous": {"all": 0.1}, "coulomb": {"all": 0.3}}, seed=args.seed,
                       inertia_perturbation=0.03, noise=NoiseTruth(encoder_counts_per_rev=524288, tau_std=0.02),
                       control=ControlTruth(rate_hz=1000.0))
    start = time.perf_counter()
    data, _ = simulate(robot, trajectory, truth, 20.0)
    sim_s = time.perf_counter() - start
    print(f"robot {robot.name}: {n} joints; simulated 20 s at 1 kHz ({data.num_samples} samples) in {sim_s:.1f} s")
    result = None

    def run():
        nonlocal result
        with single_threaded_blas(), tempfile.TemporaryDirectory() as tmp:
            result = diagnose(robot, data)
            result.write(tmp)

    repeats = max(1, min(int(args.repeats), 3))
    seconds = median_time(run, repeats=repeats, warmup=0, warmup_seconds=0.0)
    print("named: " + (", ".join(f"{e.effect}[{e.joint or e.link}] {e.value:.3g} {e.unit}" for e in result.effects)
                       or "nothing"))
    print("steps [s]: " + ", ".join(f"{k} {v:.2f}" for k, v in result.timings.items()))
    print(f"diagnosis of 20 s at 1 kHz incl. report and model files: {seconds:.2f} s (median of {repeats}; "
          "target < 30 s)")
    print(f"BENCH diagnose_s={seconds:.3f} samples={data.num_samples} joints={n}")


def bench_sensitivity(args) -> None:
    """The diagnosis's false alarms in 20 clean simulated runs of ``--trajectory`` (14 s at
    500 Hz, 5 % inertial errors, noise), then how many of 0.1 N·m joint offsets it names."""
    robot = load_robot(args.robot)
    trajectory = load_trajectory(args.trajectory)[0] if args.trajectory else bench_trajectory(robot, args.seed)
    noise = NoiseTruth(encoder_counts_per_rev=524288, tau_std=0.05)
    control = ControlTruth(rate_hz=500.0)
    alarms = []
    with single_threaded_blas():
        for k in range(20):
            truth = make_truth(robot, seed=args.seed + k, inertia_perturbation=0.05, noise=noise, control=control)
            data, _ = simulate(robot, trajectory, truth, 14.0)
            found = [f"{e.effect}[{e.joint or e.link}]" for e in diagnose(robot, data).effects]
            alarms.append(found)
            print(f"clean run {k}: " + (", ".join(found) or "nothing named"), flush=True)
        truth = make_truth(robot, {"torque_offset": {"all": 0.1}}, seed=args.seed, inertia_perturbation=0.05,
                           noise=noise, control=control)
        data, _ = simulate(robot, trajectory, truth, 14.0)
        offsets = {e.joint: e.value for e in diagnose(robot, data).effects if e.effect == "torque_offset"}
    print("0.1 N·m offsets named: " + ", ".join(f"{j} {v:+.4f}" for j, v in offsets.items()))
    false_alarms = sum(1 for found in alarms if found)
    print(f"false alarms: {false_alarms} of 20 clean runs named something; offsets named on {len(offsets)} of {robot.n} joints")
    print(f"BENCH false_alarms={false_alarms} clean_runs=20 offsets_named={len(offsets)} joints={robot.n}")


def bench_main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m pe_drake.bench", description=__doc__)
    parser.add_argument("benchmark", choices=sorted(_BENCHMARKS))
    parser.add_argument("--robot", default=None, help="robot (default: g1 for gradient, g1,ur5,two_arm_lift for solve, panda otherwise)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--trajectory", default="", help="sensitivity: trajectory.json to simulate (default: random)")
    parser.add_argument("--repeats", type=int, default=51, help="timed runs per median (default: %(default)s)")
    parser.add_argument("--default-malloc", action="store_true",
                        help="gradient: keep glibc's malloc thresholds (see pe_drake.memory)")
    parser.add_argument("--max-iterations", type=int, default=None,
                        help="solve: IPOPT budget (default: each robot's config, 300); robots: per "
                             "robot (default: 60)")
    parser.add_argument("--robots", default="", help="robots, solve: names or model paths, a,b,c (default: all; "
                        "solve: g1,ur5,two_arm_lift)")
    parser.add_argument("--harmonics", type=int, default=None, help="robots: Fourier harmonics (default: the robot's)")
    parser.add_argument("--duration", type=float, default=None,
                        help="robots: simulated seconds (default: the whole written motion)")
    parser.add_argument("--payloads", type=int, default=5, help="payload: random payloads (default: %(default)s)")
    parser.add_argument("--minutes", default="1,10,60", help="memory: log durations [min] (default: %(default)s)")
    parser.add_argument("--link", default="", help="payload: the payload link (default: the robot's flange)")
    parser.add_argument("--drive-terms", default="none", choices=["none", "friction", "all"],
                        help="gradient: identify's drive terms as columns of C too (default: %(default)s)")
    args = parser.parse_args(argv)
    if args.robot is None and args.benchmark != "solve":  # solve: its own list (bench_solve.DEFAULT_ROBOTS)
        args.robot = "g1" if args.benchmark == "gradient" else "panda"
    module = importlib.import_module(_BENCHMARKS[args.benchmark])
    getattr(module, f"bench_{args.benchmark}")(args)
    return 0


if __name__ == "__main__":
    sys.exit(bench_main())
