"""Close the loop on a simulated Panda: optimized trajectory → measured run → identified model.

1. An optimized exciting trajectory (tests/data/panda_optimized.json, made by
   ``pe-drake optimize --robot panda``) and, for validation, a random one of the same period.
2. Both are run on a "true" Panda in Drake's Simulator: inertias ±10 % off the URDF, encoder
   quantization, torque noise (``pe_drake.simulation.simulation``), logged at 1 kHz.
3. OLS, WLS and the physically consistent SDP identify the base parameters from the first run;
   each is validated on the second, next to the a-priori URDF and the true rigid-body model.
4. The physical estimate is written as a URDF Drake loads.

    python examples/identify_panda.py [--out results/identify_panda]

Takes about a minute on 2 cores (mostly the two simulations).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="results/identify_panda", help="output folder")
    parser.add_argument("--duration", type=float, default=10.0, help="simulated time per run [s]")
    args = parser.parse_args(argv)
    if not args.duration > 0:
        parser.error(f"--duration must be positive, got {args.duration}")

    from pe_drake.config import ExcitationConfig
    from pe_drake.excitation.problem import ExcitationProblem, scale_into_limits
    from pe_drake.excitation.trajectory_file import load_trajectory
    from pe_drake.identification.estimators import identify
    from pe_drake.identification.intake import prepare_measurement
    from pe_drake.identification.prediction import predict, robot_torques, torque_errors
    from pe_drake.simulation.simulation import simulate
    from pe_drake.simulation.truth import NoiseTruth, make_truth
    from pe_drake.multibody.robot import load_robot
    from pe_drake.multibody.robot_model import RobotModel
    from pe_drake.threads import single_threaded_blas

    out = Path(args.out)
    robot = load_robot("panda")
    optimized, _ = load_trajectory(ROOT / "tests" / "data" / "panda_optimized.json")
    problem = ExcitationProblem(robot, ExcitationConfig(harmonics=optimized.harmonics, omega=optimized.omega))
    alpha = problem.initial_guess(seed=7, amplitude=2.0)
    random_run = problem.trajectory(scale_into_limits(problem, alpha, 0.9))

    truth = make_truth(robot, seed=2, inertia_perturbation=0.1,
                       noise=NoiseTruth(encoder_counts_per_rev=524288, tau_std=0.05))
    runs = {}
    with single_threaded_blas():
        for name, trajectory in (("identification", optimized), ("validation", random_run)):
            start = time.perf_counter()
            print(f"simulating the {name} run ({args.duration:g} s at 1 kHz) ...", flush=True)
            measurement, info = simulate(robot, trajectory, truth, duration=args.duration)
            runs[name] = prepare_measurement(robot, measurement)
            print(f"  done in {time.perf_counter() - start:.1f} s", flush=True)
        phi_true = np.concatenate([info["phi_true"][b] for b in robot.body_names])
        ident, valid = runs["identification"], runs["validation"]

        rows = [
            ("a-priori URDF", torque_errors(valid.tau, robot_torques(robot, valid, robot.phi_model))[0], None),
            ("true rigid body", torque_errors(valid.tau, robot_torques(robot, valid, phi_true))[0], None),
        ]
        results = {}
        for method in ("ols", "wls", "physical"):
            result = identify(robot, ident, method)
            results[method] = result
            truth_B = result.base.base_values(phi_true)
            error = float(np.linalg.norm(result.phi_B - truth_B) / np.linalg.norm(truth_B))
            rows.append((method, torque_errors(valid.tau, predict(robot, result, valid))[0], error))
            print(
                f"{method:9s} cond(W) {result.cond:.3g}, {result.wall_time:.2f} s, "
                f"base-parameter error vs truth {100 * error:.3f} %"
            )

    print("\nheld-out RMS torque error [N·m] (validation run, random trajectory)")
    print(f"{'model':16s}" + "".join(f"{j[-6:]:>9s}" for j in robot.joint_names) + f"{'all':>9s}")
    for name, rms, _ in rows:
        print(f"{name:16s}" + "".join(f"{r:9.4f}" for r in rms) + f"{float(np.sqrt(np.mean(rms**2))):9.4f}")
    path = out / "model.urdf"
    RobotModel(robot.joint_names, robot.body_names, results["physical"].phi).write_urdf(path, robot)
    print(f"\nwrote {path} (physically consistent estimate; Drake loads it)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
