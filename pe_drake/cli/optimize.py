"""``pe-drake optimize``: from a robot to an optimized exciting trajectory on disk."""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import math
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from pe_drake.cli.common import config_from_args, robot_from_args
from pe_drake.config import Config, noise_vector, validate_config
from pe_drake.exceptions import ConfigError, DataError, NotWithinLimitsError
from pe_drake.excitation.constraints import constraints_from_config
from pe_drake.excitation.controller_goal import GoalOptions, goal_yaml_text, write_goal_bag
from pe_drake.excitation.fourier import FourierBasis, sample_times
from pe_drake.excitation.multistart import solve_multistart
from pe_drake.excitation.nominal import choose_nominal_posture
from pe_drake.excitation.parallel import open_executor
from pe_drake.excitation.problem import ExcitationProblem
from pe_drake.excitation.quality import QualityReport, excitation_quality
from pe_drake.excitation.ramp import RAMP_DURATIONS, RampedMotion, check_within_limits, choose_ramp_duration
from pe_drake.excitation.trajectory_file import load_motion, load_trajectory, save_trajectory, write_motion_csv
from pe_drake.io_utils import staged_output_dir
from pe_drake.multibody.capsule_fitting import ensure_capsules
from pe_drake.multibody.registry import robot_display_name
from pe_drake.output_paths import OPTIMIZE_OUTPUTS, check_output_dir, remove_stale_outputs
from pe_drake.plots import plot_trajectory
from pe_drake.viewer import write_playback_html


def prior_regressor(problem, trajectory_json: str | Path) -> np.ndarray:
    """Stacked base regressor of an earlier motion (for C0, Eq. 41), at the problem's number
    of cost samples over that motion's own period.

    Raises:
        DataError: the file's joints differ from the robot's.
    """
    trajectory, data = load_trajectory(trajectory_json)
    joints = tuple(data["joints"])
    if joints != problem.robot.joint_names:
        raise DataError(
            f"its joints {list(joints)} differ from the robot's {list(problem.robot.joint_names)}",
            file=str(trajectory_json),
        )
    check_within_limits(RampedMotion(trajectory), problem.robot.limits, joints, source=str(trajectory_json))
    basis = FourierBasis(trajectory.harmonics, trajectory.omega, sample_times(trajectory.period, problem.config.cost_samples))
    q, v, vd = basis.q(trajectory.a, trajectory.b, trajectory.q0), basis.v(trajectory.a, trajectory.b), basis.vd(
        trajectory.a, trajectory.b
    )
    Y = problem.rows(q, v, vd)  # the measurement's rows (joint torques, ground wrench or both)
    return problem.base.reduce(Y).reshape(-1, problem.base.count)


def _apply_arguments(config: Config, args: argparse.Namespace) -> Config:
    if args.solver:
        config.solver.name = args.solver
    if args.criterion:
        config.excitation.criterion = args.criterion
    if args.max_iterations is not None:
        config.solver.max_iterations = args.max_iterations
    if args.seed is not None:
        config.excitation.seed = args.seed
    if getattr(args, "measurement", None):
        config.excitation.measurement = args.measurement
    if args.quiet:
        config.solver.verbose = False
    if getattr(args, "periods", None) is not None:
        config.excitation.periods = args.periods
    if getattr(args, "no_ramp", False):
        config.excitation.ramp = False
    if args.starts is not None:
        config.parallel.starts = args.starts
    if args.workers is not None:
        if args.workers < 1:
            raise ConfigError(f"--workers must be a positive integer, got {args.workers}")
        config.parallel.workers = args.workers
    if args.executor:
        config.parallel.executor = args.executor
    if args.ray_address:
        config.parallel.executor = args.executor or "ray"
        config.parallel.address = args.ray_address
    return validate_config(config)


def optimize_command(args: argparse.Namespace) -> int:
    """Runs ``pe-drake optimize``; returns 0 on success, 1 if no valid trajectory was found."""
    _check_arguments(args)  # and every output path and --prior file: before any work
    config = config_from_args(args, lambda c: _apply_arguments(c, args))
    _check_csv_size(config, args.csv_rate)
    say = (lambda *a: None) if args.quiet else (lambda *a: print(*a, flush=True))
    start = time.perf_counter()
    out = Path(args.out)
    with tempfile.TemporaryDirectory(prefix="pe_drake_capsules_") as fit_dir:
        robot, fitted, unchecked = _load_robot(args, config, Path(fit_dir), say)
        noise_vector(config.excitation.noise_std.torque, robot.joint_names)  # refuse a bad noise_std before solving
        problem = _problem(robot, config, args.prior, say)
        constraints = constraints_from_config(robot, config.excitation, config.environment)
        if constraints:
            say("constraints: joint limits, " + ", ".join(c.name for c in constraints))
        ms = _solve_starts(robot, problem, config, say)
        result = ms.best
        say(
            f"{'valid' if result.success else 'FAILED'}: {result.message}; cond {result.cond:.5g} "
            f"(this motion alone {result.cond_motion:.5g}), seed {ms.seed}, "
            f"{result.nit if result.nit is not None else '-'} iterations, {result.nfev} evaluations, {result.wall_time:.1f} s"
        )
        say("minimum margins at 1 kHz: " + ", ".join(f"{k} {m:.4g}" for k, m in result.margins.items()))
        motion = _ramped_motion(result, robot, constraints, config, say) if result.success else None
        quality = _quality(problem, result, constraints, config) if result.success else None
        for line in quality.summary_lines() if quality is not None else []:
            say(line)
        report = _report(robot, problem, config, ms, args.prior, time.perf_counter() - start)
        report.update(_safety_report(robot, config, motion, fitted, args.out))
        report["quality"] = quality.to_dict() if quality is not None else None
        goal, refusal = _controller_goal(motion, robot, config, say) if result.success else (None, None)
        report["unchecked"] = unchecked
        if unchecked:
            say(f"NOT checked ({len(unchecked)}): " + "; ".join(unchecked[:5]) + (" ..." if len(unchecked) > 5 else ""))
            if refusal is None and not getattr(args, "allow_unchecked", False):
                refusal = (f"{len(unchecked)} part(s) of the robot were not checked for collision (listed in "
                           "report.json 'unchecked'); give robot.capsules, or --allow-unchecked to write it anyway")
        report["not_valid_for_hardware"] = refusal
        with staged_output_dir(out) as tmp:
            if result.success and refusal is None:
                _write_success_outputs(tmp, robot, result, motion, args, say, quality)
                if goal is not None:
                    (tmp / "trajectory_goal.yaml").write_text(goal)
                    write_goal_bag(tmp / "trajectory_goal_bag", motion, robot.joint_names, GoalOptions.from_config(config))
            if fitted is not None:
                shutil.copyfile(fitted.path, tmp / fitted.path.name)
            (tmp / "report.json").write_text(json.dumps(report, indent=2, default=float))
            written = [p.name for p in tmp.iterdir()]
    remove_stale_outputs(out, OPTIMIZE_OUTPUTS, written)  # a reused --out never mixes runs
    if refusal is not None:
        print(f"pe-drake optimize: not valid for hardware: {refusal}. Only {out / 'report.json'} was written.",
              file=sys.stderr)
        return 1
    if not result.success:
        print(
            f"pe-drake optimize: no valid trajectory: {result.message}. Only {out / 'report.json'} was "
            "written. Try more iterations (--max-iterations), more starts (--starts), another seed (--seed), "
            "or looser margins.",
            file=sys.stderr,
        )
        return 1
    say(f"wrote {out}/" + ", ".join(sorted(written)))
    return 0


def _check_arguments(args: argparse.Namespace) -> None:
    check_output_dir(args.out)
    if not (math.isfinite(args.csv_rate) and 1.0 <= args.csv_rate <= 10_000.0):
        raise ConfigError(f"--csv-rate must be from 1 to 10000 Hz, got {args.csv_rate:g}")
    if args.seed is not None and not 0 <= args.seed < 2**32:
        raise ConfigError(f"--seed must be an integer from 0 to 2^32 - 1, got {args.seed}")
    if args.periods is not None and not 1 <= args.periods <= 1000:
        raise ConfigError(f"--periods must be an integer from 1 to 1000, got {args.periods}")
    for prior in args.prior:
        load_motion(prior)  # every value of the file, ramps included


def _check_csv_size(config: Config, rate: float, max_rows: int = 10_000_000) -> None:
    """Refuses a trajectory.csv too large to write (periods × period × rate, ramps included)."""
    e = config.excitation
    duration = e.periods * 2 * math.pi / e.omega + (2 * max(RAMP_DURATIONS) if e.ramp else 0.0)
    if duration * rate > max_rows:
        raise ConfigError(
            f"trajectory.csv would hold up to {duration * rate:.3g} rows ({e.periods} period(s) of "
            f"{2 * math.pi / e.omega:.4g} s at {rate:g} Hz); use fewer --periods or a lower --csv-rate "
            f"(at most {max_rows:.0e} rows)"
        )


def _load_robot(args, config: Config, fit_dir: Path, say):
    """The robot, with capsules fitted to its meshes when it has none (and needs them)."""
    name = robot_display_name(args.robot)
    try:
        fitted = ensure_capsules(config, fit_dir)
    except ConfigError as err:
        if config.excitation.collision_margin >= 0 or config.environment.boxes:
            raise
        say(f"warning: {err}; the floor is NOT checked (environment.floor turned off)")
        config.environment.floor, fitted = False, None
        unchecked = [f"floor: no collision geometry to check it with ({err})"] + list(getattr(err, "unchecked", ()))
    else:
        unchecked = list(fitted.unchecked) if fitted is not None else []
    if fitted is not None:
        say(
            f"no capsule file for {name}: fitted capsules: {fitted.summary()}; written to {Path(args.out) / fitted.path.name}; "
            f"self-collision margin {config.excitation.collision_margin:g} m"
            + (f", {len(fitted.ignored_pairs)} pair(s) touching by design ignored" if fitted.ignored_pairs else "")
        )
    robot = robot_from_args(args, config, show_notes=False)  # after the capsules are fitted
    say(f"robot {robot.name}: {robot.n} excited joints, {robot.num_bodies} moving bodies")
    for note in assumed_defaults(config, robot.joint_names):
        say(f"note: {note}")
    for note in robot.notes:  # what the model needed for Drake (mimic, repeated materials)
        say(f"note: {note}")
    nominal = choose_nominal_posture(robot, config.excitation, config.environment)
    if nominal is not None:
        say(f"note: {nominal}")
    return robot, fitted, unchecked


def _quality(problem, result, constraints, config: Config) -> QualityReport:
    """The quality figures of the optimized motion (issue 13), for ``excitation.periods``
    periods when the config has that setting (else one)."""
    periods = int(getattr(config.excitation, "periods", 1))
    return excitation_quality(problem, result.x, constraints, noise_std=config.excitation.noise_std.torque, periods=periods)


def _problem(robot, config: Config, priors: list[str], say):
    """The excitation problem, with the prior motions' regressors as C0 (Eq. 41)."""
    problem = ExcitationProblem(robot, config.excitation)
    if priors:
        blocks = [prior_regressor(problem, p) for p in priors]
        problem = ExcitationProblem(robot, config.excitation, C0=np.vstack(blocks), base=problem.base, model=problem.model)
        say(f"prior data: {len(priors)} motion(s), {problem.C0.shape[0]} rows, cond(C0) = {np.linalg.cond(problem.C0):.4g}")
    say(
        f"{problem.base.count} base parameters of the {config.excitation.measurement} rows; {problem.num_variables} variables "
        f"(N = {problem.harmonics}, ω = {problem.omega:.4g} rad/s, period {problem.period:.3g} s); "
        f"T = {config.excitation.cost_samples} cost samples, K = {config.excitation.constraint_samples} constraint samples"
    )
    return problem


def _solve_starts(robot, problem, config: Config, say):
    """Multi-start (start k: seed + k) on the configured executor; the best feasible start is kept."""
    par = config.parallel
    seeds = [config.excitation.seed + k for k in range(par.starts)]
    executor = open_executor(
        robot,
        par.executor,
        par.workers or None,
        tasks=par.starts,
        address=par.address,
        base=problem.base,
        constraints_factory=functools.partial(constraints_from_config, environment=config.environment),
    )
    with executor:
        where = "in this process" if executor.name == "main" else f"on {executor.workers} {executor.name} worker(s)"
        say(
            f"solving {par.starts} start(s) (seeds {seeds[0]}..{seeds[-1]}) {where} with {config.solver.name} "
            f"(max {config.solver.max_iterations} iterations) ..."
        )

        def progress(event) -> None:
            if event.kind != "progress" or config.solver.verbose:
                say(str(event))

        return solve_multistart(
            None, config.excitation, config.solver, seeds, C0=problem.C0, executor=executor, progress=progress
        )


def _report(robot, problem, config: Config, ms, priors: list[str], total_time: float) -> dict:
    result = ms.best
    return {
        "robot": robot.name,
        "success": result.success,
        "message": result.message,
        "status": result.status,
        "solver": result.solver,
        "criterion": config.excitation.criterion,
        "measurement": config.excitation.measurement,
        "cond": result.cond,
        "cond_motion": result.cond_motion,
        "criterion_value": result.fun,
        "iterations": result.nit,
        "evaluations": result.nfev,
        "seed": ms.seed,
        "solve_time_s": result.wall_time,
        "multistart_time_s": ms.wall_time,
        "total_time_s": total_time,
        "executor": {"name": ms.executor, "workers": ms.workers, "address": config.parallel.address},
        "starts": [
            {"seed": s.seed, "cond": s.cond, "success": s.success, "time_s": s.wall_time, "task_time_s": s.task_time,
             "worker": s.worker, "criterion_value": s.fun, "message": s.message}
            for s in ms.starts
        ],
        "margins_1khz": result.margins,
        "base_parameters": problem.base.count,
        "base_parameter_names": list(problem.base.base_names),
        "singular_values": result.singular_values.tolist(),
        "prior": [str(p) for p in priors],
        "config": dataclasses.asdict(config),
    }


def _write_success_outputs(tmp: Path, robot, result, motion, args, say, quality: QualityReport | None = None) -> None:
    save_trajectory(
        tmp / "trajectory.json", robot, result.trajectory, cond=result.cond, cond_motion=result.cond_motion,
        **motion.to_dict(),
    )
    write_motion_csv(tmp / "trajectory.csv", robot.joint_names, motion, args.csv_rate)
    plot_trajectory(
        tmp / "trajectory.png",
        robot,
        result.trajectory,
        result.singular_values,
        title=f"{robot.name}: cond {result.cond:.4g}",
        note=quality.figure_note() if quality is not None else "",
    )
    if not args.no_html:
        try:
            write_playback_html(tmp / "trajectory.json", tmp / "playback.html", config=args.config)
        except Exception as err:  # the playback is a convenience: never lose the trajectory over it
            say(f"warning: could not write the HTML playback: {err}")


def _controller_goal(motion, robot, config: Config, say) -> tuple[str | None, str | None]:
    """(trajectory_goal.yaml's text or None, the reason the motion is refused or None).

    The goal is the FollowJointTrajectory a ros2_control controller runs as it is; a motion
    without ramps does not start at rest and gets none. A jerk above ``robot.jerk_limits``
    refuses the whole motion: the CSV would carry the same jerk.
    """
    if motion.ramp_duration <= 0:
        say("no trajectory_goal.yaml: the motion has no ramps, so it does not start at rest")
        return None, None
    try:
        return goal_yaml_text(motion, robot.joint_names, GoalOptions.from_config(config)), None
    except NotWithinLimitsError as err:
        return None, str(err)


def assumed_defaults(config: Config, joint_names) -> list[str]:
    """Limits pe_drake assumed because neither the model nor the config gives them."""
    r = config.robot
    missing = [j for j in joint_names if j not in r.acceleration_limits]
    if not missing:
        return []
    return [
        f"acceleration limit {r.default_acceleration_limit:g} rad/s² assumed for {', '.join(missing)} "
        "(robot.default_acceleration_limit; set robot.acceleration_limits from the robot's datasheet)"
    ]


def _ramped_motion(result, robot, constraints, config, say):
    """The controller motion: ramp-in + N periods + ramp-out (or N periods without ramps)."""
    periods = config.excitation.periods
    if not config.excitation.ramp:
        say(f"ramps off (excitation.ramp: false): trajectory.csv is {periods} period(s) and does NOT start at rest")
        return RampedMotion(result.trajectory, periods, 0.0)
    motion, checks = choose_ramp_duration(result.trajectory, robot.limits, constraints, periods=periods)
    last = checks[-1]
    say(
        f"ramps from and to rest: {motion.ramp_duration:g} s each (join phase {motion.phase:.3g} s), "
        f"{periods} period(s); trajectory.csv spans {motion.duration:.4g} s, the periodic part "
        f"[{motion.periodic_start:.4g}, {motion.periodic_end:.4g}] s; ramp margins at 1 kHz: "
        + ", ".join(f"{k} {m:.4g}" for k, m in last.margins.items())
    )
    return motion


def _safety_report(robot, config: Config, motion, fitted, out) -> dict:
    """report.json's issue-10 entries: assumed limits, fitted capsules, the controller motion."""
    return {
        "assumed_defaults": assumed_defaults(config, robot.joint_names),
        "fitted_capsules": str(Path(out) / fitted.path.name) if fitted is not None else None,
        "motion": motion.to_dict() if motion is not None else None,
    }
