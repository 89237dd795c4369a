"""A humanoid without joint-torque sensors: excite and identify G1's arms from the ground wrench.

HRP-4, the paper's robot, has no joint-torque sensors; humanoids like it are
identified from the six unactuated rows of their dynamics, the wrench the ground applies
(foot force/torque sensors or a force plate). Here, on the Unitree G1 standing still with
its 14 arm joints moving (models/g1.yaml: pelvis welded, balance and capsules as in the
paper's experiment):

1. optimize one motion for the wrench rows (``excitation: {measurement: base_wrench}``) and
   one for the joint torques (today's default), from the same start, and draw random motions
   that keep balance and collision (the paper's baseline); compare cond of the wrench rows;
2. simulate the wrench-optimized motion on a "true" G1 (inertias ±10 %) and record the
   ground wrench with 0.5 N / 0.05 N·m force/torque noise; simulate the torque-optimized
   motion with 0.05 N·m joint-torque noise;
3. identify the base parameters from the wrench alone (OLS, WLS, physical) and from the
   torques alone, and compare both with the truth;
4. predict the arm torques of a third run (a random balanced motion) that the wrench data
   never saw.

    python examples/humanoid_base_wrench.py --out results/base_wrench            # full run
    python examples/humanoid_base_wrench.py --quick --out /tmp/base_wrench_quick # smoke test

Outputs in --out: summary.json, wrench_singular_values.png, wrench_torque_prediction.png, and
trajectory.json of each optimized motion. Moving the legs (a closed chain through two feet on
the ground) is out of scope: the pelvis stays welded.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

FORCE_STD = 0.5  # [N] force/torque sensor noise of the simulated runs
MOMENT_STD = 0.05  # [N·m]
TORQUE_STD = 0.05  # [N·m] joint-torque noise of the torque-sensing run
METHODS = ("ols", "wls", "physical")
RANDOM_AMPLITUDE = 0.1  # [rad] random balanced motions (at 0.15 only ~1 % of draws keep balance)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="results/base_wrench", help="output folder")
    parser.add_argument("--quick", action="store_true", help="smoke test: few iterations, short runs")
    parser.add_argument("--max-iterations", type=int, help="IPOPT iterations per motion (default 150; quick 10)")
    parser.add_argument("--candidates", type=int, help="random balanced motions drawn (default 20; quick 3)")
    parser.add_argument("--duration", type=float, help="simulated time per run [s] (default 8; quick 2)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the optimizer's start and of the truth")
    parser.add_argument("--trajectories", nargs=2, metavar=("WRENCH_JSON", "TORQUE_JSON"),
                        help="reuse two optimized motions instead of optimizing (e.g. tests/data/"
                             "g1_base_wrench_optimized.json tests/data/g1_joint_torque_optimized.json)")
    return parser


def optimize_both(robot, config, iterations: int, out: Path, say) -> dict:
    """The wrench-optimized and the torque-optimized motion from the same start, saved in out."""
    from pe_drake.excitation.constraints import constraints_from_config
    from pe_drake.excitation.solve import optimize_excitation
    from pe_drake.excitation.trajectory_file import save_trajectory

    solver = dataclasses.replace(config.solver, max_iterations=iterations, verbose=False)
    motions = {}
    for kind, name in (("base_wrench", "wrench-optimized"), ("joint_torque", "torque-optimized")):
        excitation = dataclasses.replace(config.excitation, measurement=kind)
        start = time.perf_counter()
        result = optimize_excitation(robot, excitation, solver, constraints=constraints_from_config(robot, excitation))
        say(f"optimized for {kind}: cond {result.cond:.4g}, {result.message}, {time.perf_counter() - start:.0f} s")
        path = out / f"{kind}_trajectory.json"
        save_trajectory(path, robot, result.trajectory, cond=result.cond, cond_motion=result.cond_motion)
        motions[name] = result.trajectory
    return motions


def load_motions(paths: Sequence[str], robot) -> dict:
    """The two optimized motions of an earlier run (``--trajectories``)."""
    from pe_drake.excitation.trajectory_file import load_trajectory

    motions = {}
    for name, path in zip(("wrench-optimized", "torque-optimized"), paths):
        trajectory, data = load_trajectory(path)
        if tuple(data["joints"]) != robot.joint_names:
            raise SystemExit(f"{path}: joints {data['joints']} are not G1's arm joints")
        motions[name] = trajectory
    return motions


def wrench_conds(robot, config, alphas: dict, candidates: int, seed: int, say) -> tuple[dict, object]:
    """cond of the wrench rows of each motion, and the best of the random balanced motions."""
    from pe_drake.excitation.baseline import generate_candidates
    from pe_drake.excitation.constraints import constraints_from_config
    from pe_drake.excitation.problem import ExcitationProblem

    excitation = dataclasses.replace(config.excitation, measurement="base_wrench")
    problem = ExcitationProblem(robot, excitation)
    conds = {name: float(np.linalg.cond(problem.stacked(alpha))) for name, alpha in alphas.items()}
    start = time.perf_counter()
    # The draws are scored on the wrench rows' own base parameters (excitation.measurement).
    cset = generate_candidates(
        robot, excitation, candidates, seed=1_000_000 + seed, amplitude=RANDOM_AMPLITUDE,
        constraints_factory=constraints_from_config,
    )
    best = min(cset.candidates, key=lambda c: c.cond)
    conds["random balanced (best)"] = best.cond
    took = time.perf_counter() - start
    say(f"{len(cset.candidates)} random balanced motions in {took:.0f} s, best wrench cond {best.cond:.4g}")
    return conds, problem.trajectory(best.alpha), problem


def simulate_runs(robot, trajectories: dict, duration: float, seed: int, say) -> tuple[dict, np.ndarray]:
    """Preprocessed runs (wrench and torques recorded) and the true parameters.

    The identification runs carry sensor noise; the validation run records the torques the
    motors apply without noise, so the held-out error measures the model, not the sensor.
    """
    from pe_drake.identification.intake import prepare_measurement
    from pe_drake.simulation.simulation import simulate
    from pe_drake.simulation.truth import NoiseTruth, make_truth

    noise = NoiseTruth(tau_std=TORQUE_STD, force_std=FORCE_STD, moment_std=MOMENT_STD)
    noisy = make_truth(robot, seed=seed, inertia_perturbation=0.1, noise=noise)
    clean = make_truth(robot, seed=seed, inertia_perturbation=0.1)  # the same true robot (same seed)
    runs = {}
    for name, trajectory in trajectories.items():
        start = time.perf_counter()
        truth = clean if name == "validation" else noisy
        measurement, info = simulate(robot, trajectory, truth, duration=duration, measurement="both")
        runs[name] = prepare_measurement(
            robot, measurement, fundamental_hz=trajectory.omega / (2 * np.pi), harmonics=trajectory.harmonics
        )
        say(f"simulated the {name} run ({duration:g} s at 1 kHz) in {time.perf_counter() - start:.0f} s")
    phi_true = np.concatenate([info["phi_true"][b] for b in robot.body_names])
    return runs, phi_true


def identify_and_predict(robot, runs: dict, phi_true: np.ndarray, say) -> dict:
    """Wrench-only and torque-only identification; held-out torque prediction."""
    from pe_drake.identification.estimators import identify
    from pe_drake.identification.prediction import predict, robot_torques

    held_out = runs["validation"]
    tau = held_out.tau
    rms = np.sqrt(np.mean(tau**2, axis=0))

    def held_out_error(predicted):
        e = np.sqrt(np.mean((predicted - tau) ** 2, axis=0))
        pct = 100 * e / rms
        return {"rms_error": e.tolist(), "percent_of_rms": pct.tolist(), "worst_percent": float(pct.max())}

    rows = {"a-priori model": held_out_error(robot_torques(robot, held_out, robot.phi_model))}
    rows["true rigid body"] = held_out_error(robot_torques(robot, held_out, phi_true))
    models = {}
    for measurement, run in (("base_wrench", "wrench-optimized"), ("joint_torque", "torque-optimized")):
        for method in METHODS:
            result = identify(robot, runs[run], method, measurement=measurement)
            truth_B = result.base.base_values(phi_true)
            error = np.abs(result.phi_B - truth_B) / np.maximum(np.abs(truth_B), 1e-12)
            label = f"{measurement} {method}"
            rows[label] = held_out_error(predict(robot, result, held_out))
            rows[label]["base_parameters"] = result.base.count
            rows[label]["parameter_error_norm_percent"] = float(
                100 * np.linalg.norm(result.phi_B - truth_B) / np.linalg.norm(truth_B)
            )
            rows[label]["parameter_error_median_percent"] = float(100 * np.median(error))
            models[label] = result
            say(
                f"{label:22s} {result.base.count} base parameters, cond(W) {result.cond:.4g}, error vs truth "
                f"{rows[label]['parameter_error_norm_percent']:.3f} % (norm), held-out torques within "
                f"{rows[label]['worst_percent']:.2f} % of their RMS (worst joint)"
            )
    return {"rows": rows, "models": models}


def plot(out: Path, robot, conds: dict, problem, alphas: dict, runs: dict, models: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pe_drake.excitation.criteria import evaluate_criterion
    from pe_drake.identification.prediction import predict

    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    for name, alpha in alphas.items():
        s = evaluate_criterion(problem.stacked(alpha), gradient=False).singular_values
        ax.semilogy(s / s[0], label=f"{name} (cond {conds[name]:.0f})")
    ax.set_xlabel("index")
    ax.set_ylabel("σ_i / σ_max of the wrench rows")
    ax.set_title("G1 arms: ground-wrench rows C, noise-weighted")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "wrench_singular_values.png", dpi=110)
    plt.close(fig)

    from pe_drake.identification.prediction import robot_torques

    held_out = runs["validation"]
    predicted = predict(robot, models["base_wrench wls"], held_out)
    prior = robot_torques(robot, held_out, robot.phi_model)
    joints = [0, 3, 7, 10]  # shoulder pitch and elbow of each arm
    fig, axes = plt.subplots(len(joints), 1, figsize=(6.4, 6.4), sharex=True)
    for ax, j in zip(axes, joints):
        ax.plot(held_out.t, held_out.tau[:, j], "k", lw=1.0, label="measured (simulated)")
        ax.plot(held_out.t, prior[:, j], color="0.6", lw=0.8, label="a-priori model (URDF)")
        ax.plot(held_out.t, predicted[:, j], "C1--", lw=1.0, label="predicted from the wrench model (WLS)")
        ax.set_ylabel(f"{robot.joint_names[j].replace('_joint', '')}\n[N·m]", fontsize=7)
    axes[0].legend(fontsize=7, loc="upper right")
    axes[-1].set_xlabel("t [s]")
    fig.suptitle("Held-out arm torques predicted from a wrench-only identification", fontsize=9)
    fig.tight_layout()
    fig.savefig(out / "wrench_torque_prediction.png", dpi=110)
    plt.close(fig)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from pe_drake.multibody.registry import resolve_robot_config
    from pe_drake.multibody.robot import load_robot
    from pe_drake.threads import single_threaded_blas

    iterations = args.max_iterations or (10 if args.quick else 150)
    candidates = args.candidates or (3 if args.quick else 20)
    duration = args.duration or (3.0 if args.quick else 8.0)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    say = lambda text: print(text, flush=True)  # noqa: E731
    config = resolve_robot_config("g1")
    config.excitation.seed = args.seed
    config.excitation.noise_std.force, config.excitation.noise_std.moment = FORCE_STD, MOMENT_STD
    robot = load_robot(config)
    start = time.perf_counter()
    with single_threaded_blas():
        if args.trajectories:
            motions = load_motions(args.trajectories, robot)
        else:
            motions = optimize_both(robot, config, iterations, out, say)
        alphas = {name: trajectory.alpha for name, trajectory in motions.items()}
        conds, random_run, problem = wrench_conds(robot, config, alphas, candidates, args.seed, say)
        runs, phi_true = simulate_runs(robot, {**motions, "validation": random_run}, duration, args.seed, say)
        found = identify_and_predict(robot, runs, phi_true, say)
        plot(out, robot, conds, problem, alphas, runs, found["models"])
    ratio_torque = conds["torque-optimized"] / conds["wrench-optimized"]
    ratio_random = conds["random balanced (best)"] / conds["wrench-optimized"]
    summary = {
        "wrench_cond": conds,
        "ratio_torque_optimized": ratio_torque,
        "ratio_random_best": ratio_random,
        "held_out": found["rows"],
        "settings": {"iterations": None if args.trajectories else iterations, "trajectories": args.trajectories,
                     "candidates": candidates, "duration_s": duration, "seed": args.seed,
                     "force_std": FORCE_STD, "moment_std": MOMENT_STD, "torque_std": TORQUE_STD},
        "wall_time_s": time.perf_counter() - start,
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    say("\ncond of the ground-wrench rows (noise-weighted):")
    for name, value in conds.items():
        say(f"  {name:24s} {value:9.1f}")
    say(f"  torque-optimized / wrench-optimized {ratio_torque:.1f}x, random best / wrench-optimized {ratio_random:.1f}x")
    say("\nheld-out arm torques (random balanced run), RMS error in % of each joint's RMS:")
    for name, row in found["rows"].items():
        pct = np.asarray(row["percent_of_rms"])
        say(f"  {name:22s} median {np.median(pct):6.2f} %, worst {pct.max():6.2f} %")
    say(f"\nwrote {out}/summary.json and two figures ({summary['wall_time_s']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
