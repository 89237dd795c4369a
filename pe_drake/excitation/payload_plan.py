"""The front door of ``pe-drake optimize --payload``: :func:`optimize_payload` builds a payload
motion from the arm's config (its constraints and noise kept), and :func:`write_payload_plan`
writes trajectory.json (with ``payload_link``), trajectory.csv and report.json, all or nothing."""

from __future__ import annotations

import dataclasses
import json
import math
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path

from pe_drake.config import Config
from pe_drake.config_sections import noise_vector
from pe_drake.exceptions import ConfigError
from pe_drake.excitation.constraints import constraints_from_config
from pe_drake.excitation.motion_plan import collision_geometry
from pe_drake.excitation.payload_motion import PayloadMotionPlan, optimize_payload_motion, payload_excitation_config
from pe_drake.io_utils import finite_json, staged_output_dir
from pe_drake.multibody.robot import Robot
from pe_drake.output_paths import OPTIMIZE_OUTPUTS, check_output_dir

#: The arm's excitation settings a payload motion keeps (its constraints and noise).
KEPT_SETTINGS = ("balance_radius", "collision_margin", "torque_limits", "noise_std", "seed", "measurement")


def optimize_payload(config: Config, robot: Robot, link: str, *, seed: int | None = None, criterion: str | None = None,
                     max_iterations: int | None = None, allow_unchecked: bool = False,
                     progress: Callable[[str], None] | None = None) -> PayloadMotionPlan:
    """A short motion that excites the payload on ``link`` alone, within the arm's limits,
    constraints and noise (:func:`~pe_drake.excitation.payload_motion.optimize_payload_motion`).

    Self-collision is set up as plain ``optimize`` does it (issue 37).

    Raises:
        ConfigError, NoSolutionFound: bad settings, parts of the robot that cannot be checked
            for collision (unless ``allow_unchecked``), or no valid motion.
    """
    say = progress or (lambda _line: None)
    fit_dir = tempfile.mkdtemp(prefix="pe_drake_capsules_")
    try:
        return _optimize(config, robot, link, fit_dir, seed, criterion, max_iterations, allow_unchecked, say)
    finally:
        shutil.rmtree(fit_dir, ignore_errors=True)  # fitted capsules live in the robot once it is built


def _optimize(config, robot: Robot, link, fit_dir, seed, criterion, max_iterations, allow_unchecked, say) -> PayloadMotionPlan:
    config, fitted, unchecked = collision_geometry(config, fit_dir, say)
    if unchecked and not allow_unchecked:
        raise ConfigError(f"{len(unchecked)} part(s) of the robot cannot be checked for collision: "
                          + "; ".join(unchecked[:5]) + "; give robot.capsules, or --allow-unchecked to write it anyway")
    for part in unchecked:
        say(f"NOT checked: {part}")
    if fitted is not None:  # the robot with the capsules just fitted
        robot = Robot(robot.name, config.robot)
    arm = config.excitation
    changes = {k: getattr(arm, k) for k in KEPT_SETTINGS}
    changes.update({k: v for k, v in (("seed", seed), ("criterion", criterion)) if v is not None})
    excitation = payload_excitation_config(**changes)
    solver = dataclasses.replace(config.solver, verbose=False, max_iterations=max_iterations or 150)
    constraints = constraints_from_config(robot, excitation, config.environment)
    noise = noise_vector(arm.noise_std.torque, robot.joint_names)
    say(f"payload motion for {link} on {robot.name}: {excitation.harmonics} harmonics, period "
        f"{2 * math.pi / excitation.omega:.3g} s, criterion {excitation.criterion}; constraints: joint limits"
        + "".join(f", {c.name}" for c in constraints))
    plan = optimize_payload_motion(robot, link, excitation, solver, constraints=constraints, noise_std=noise)
    say(f"{plan.result.message}; cond(Y_L) {plan.result.cond:.4g}; motion {plan.motion.duration:.3g} s "
        f"(ramps {plan.motion.ramp_duration:g} s); {plan.wall_time:.1f} s")
    for line in plan.expected.summary_lines():
        say(line)
    return plan


def write_payload_plan(plan: PayloadMotionPlan, folder: str | Path, robot: Robot, csv_rate: float = 1000.0) -> list[str]:
    """Writes trajectory.json, trajectory.csv and report.json into ``folder``; returns the names."""
    out = check_output_dir(folder)
    with staged_output_dir(out, "report.json", OPTIMIZE_OUTPUTS) as tmp:
        plan.write(tmp, robot, csv_rate)
        report = {"robot": robot.name, "payload_link": plan.link, "cond": plan.result.cond,
                  "criterion": plan.criterion, "message": plan.result.message,
                  "motion_duration": plan.motion.duration, "optimize_time_s": plan.wall_time,
                  "expected": plan.expected.to_dict(), "margins_1khz": plan.result.margins}
        (tmp / "report.json").write_text(json.dumps(finite_json(report), indent=2))
    return ["trajectory.json", "trajectory.csv", "report.json"]
