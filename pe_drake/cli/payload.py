"""``pe-drake optimize --payload LINK`` and ``pe-drake identify --payload LINK``: faces over
:func:`~pe_drake.excitation.payload_motion.optimize_payload_motion` and
:func:`~pe_drake.identification.payload.identify_payload` (issue 24)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

from pe_drake.cli.common import config_from_args, robot_from_args
from pe_drake.config import noise_vector
from pe_drake.exceptions import ConfigError
from pe_drake.excitation.constraints import constraints_from_config
from pe_drake.excitation.payload_motion import optimize_payload_motion, payload_excitation_config
from pe_drake.excitation.trajectory_file import load_trajectory
from pe_drake.identification.estimators import prepare_measurement
from pe_drake.identification.identified_file import load_identified
from pe_drake.identification.intake import read_measurements
from pe_drake.identification.payload import PayloadBox, PayloadOptions, arm_parameters, check_payload_trajectory, identify_payload
from pe_drake.identification.payload_formats import vendor_formats, write_payload_urdf
from pe_drake.io_utils import staged_output_dir
from pe_drake.output_paths import check_output_dir

#: The arm's excitation settings a payload motion keeps (its constraints and noise).
_KEPT = ("balance_radius", "collision_margin", "torque_limits", "noise_std", "seed", "measurement")


def payload_optimize_command(args: argparse.Namespace) -> int:
    """Optimizes a payload motion: trajectory.json (with ``payload_link``), trajectory.csv, report.json."""
    check_output_dir(args.out)
    say = (lambda *a: None) if args.quiet else (lambda *a: print(*a, flush=True))
    config = config_from_args(args)
    robot = robot_from_args(args, config)
    arm = config.excitation
    changes = {k: getattr(arm, k) for k in _KEPT}
    if args.seed is not None:
        changes["seed"] = args.seed
    if args.criterion:
        changes["criterion"] = args.criterion
    excitation = payload_excitation_config(**changes)
    solver = dataclasses.replace(config.solver, verbose=False, max_iterations=args.max_iterations or 150)
    constraints = constraints_from_config(robot, excitation, config.environment)
    noise = noise_vector(arm.noise_std.torque, robot.joint_names)
    say(f"payload motion for {args.payload} on {robot.name}: {excitation.harmonics} harmonics, period "
        f"{2 * 3.141592653589793 / excitation.omega:.3g} s, criterion {excitation.criterion}; constraints: joint limits"
        + "".join(f", {c.name}" for c in constraints))
    plan = optimize_payload_motion(robot, args.payload, excitation, solver, constraints=constraints, noise_std=noise)
    say(f"{plan.result.message}; cond(Y_L) {plan.result.cond:.4g}; motion {plan.motion.duration:.3g} s "
        f"(ramps {plan.motion.ramp_duration:g} s); {plan.wall_time:.1f} s")
    for line in plan.expected.summary_lines():
        say(line)
    with staged_output_dir(Path(args.out)) as tmp:
        plan.write(tmp, robot, args.csv_rate)
        report = {"robot": robot.name, "payload_link": args.payload, "cond": plan.result.cond,
                  "criterion": excitation.criterion, "message": plan.result.message,
                  "motion_duration": plan.motion.duration, "optimize_time_s": plan.wall_time,
                  "expected": plan.expected.to_dict(), "margins_1khz": plan.result.margins}
        (tmp / "report.json").write_text(json.dumps(report, indent=2, default=float))
    say(f"wrote {args.out}/trajectory.json, trajectory.csv, report.json")
    return 0


def _read_runs(robot, paths, args) -> list:
    runs = []
    for path in paths:
        raw = read_measurements(path, robot)
        runs.append(prepare_measurement(robot, raw, cutoff_hz=args.cutoff, filtering=not args.no_filter))
    return runs


def _box(text: str | None) -> PayloadBox | None:
    if not text:
        return None
    try:
        values = [float(x) for x in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 6:
        raise ConfigError(f"--payload-box takes cx,cy,cz,sx,sy,sz [m] in the payload link's frame, got {text!r}")
    return PayloadBox(tuple(values[:3]), tuple(values[3:]))


def payload_identify_command(args: argparse.Namespace) -> int:
    """Identifies a payload: payload.json (with the vendor formats) and model_with_payload.urdf."""
    check_output_dir(args.out)
    start = time.perf_counter()
    config = config_from_args(args)
    robot = robot_from_args(args, config)
    if args.trajectory:
        _, data = load_trajectory(args.trajectory)
        check_payload_trajectory(data, args.payload, args.trajectory)
    loaded = _read_runs(robot, args.data, args)
    unloaded = _read_runs(robot, args.unloaded or [], args)
    arm = load_identified(args.model, robot) if args.model else None
    result = identify_payload(robot, loaded, unloaded, args.payload, arm, PayloadOptions(box=_box(args.payload_box)))
    formats = vendor_formats(robot, result.payload, result.link, args.flange or None)
    p = result.payload
    print(f"payload on {result.link} ({len(loaded)} loaded, {len(unloaded)} unloaded run(s), {result.samples} samples, "
          f"{result.wall_time:.2f} s): mass {p.mass:.4f} ± {result.mass_std:.2g} kg, CoM "
          f"{[round(float(x), 5) for x in p.com]} ± {[float(f'{x:.2g}') for x in result.com_std]} m")
    if not unloaded:
        print("note: no unloaded run: the arm's model errors go into the payload (give --unloaded, same motion)")
    print(f"in {formats['flange']}: Franka setLoad mass {formats['franka']['load_mass']:.4f}, "
          f"F_x_Cload {[round(float(x), 5) for x in formats['franka']['F_x_Cload']]}")
    print("UR: " + formats["ur"]["set_target_payload"])
    print("KUKA: " + formats["kuka"]["krl"])
    with staged_output_dir(Path(args.out)) as tmp:
        d = result.to_dict()
        d["vendor"] = formats
        (tmp / "payload.json").write_text(json.dumps(d, indent=2))
        write_payload_urdf(tmp / "model_with_payload.urdf", robot, p, result.link, arm_parameters(robot, arm))
    print(f"wrote {args.out}/payload.json, model_with_payload.urdf ({time.perf_counter() - start:.1f} s)")
    return 0
