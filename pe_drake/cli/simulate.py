"""``pe-drake simulate``: a measured run of a perturbed 'true' robot, written as CSV + truth JSON."""

from __future__ import annotations

import json

from pe_drake.cli.common import config_from_args, measurement_from_args, robot_from_args
from pe_drake.exceptions import ConfigError, DataError
from pe_drake.excitation.ramp import check_within_limits
from pe_drake.excitation.trajectory_file import load_motion
from pe_drake.identification.measurements import measurement_to_csv_text
from pe_drake.identification.simulation import simulate, truth_path_for
from pe_drake.identification.truth import load_truth
from pe_drake.io_utils import atomic_write_text
from pe_drake.output_paths import check_output_file


def simulate_command(args) -> int:
    """``pe-drake simulate``: writes the CSV and its ``.truth.json``; prints a summary."""
    out = check_output_file(args.out, "--out", (".csv",))  # before any work
    motion, data = load_motion(args.trajectory)  # validated before any work
    truth = load_truth(args.truth)
    config = config_from_args(args)
    measurement = measurement_from_args(args, config)
    robot = robot_from_args(args, config)
    if list(data["joints"]) != list(robot.joint_names):
        raise DataError(
            f"trajectory joints {', '.join(data['joints'])} differ from robot '{robot.name}''s "
            f"excited joints {', '.join(robot.joint_names)}",
            file=str(args.trajectory),
        )
    check_within_limits(motion, robot.limits, robot.joint_names, source=str(args.trajectory))
    # The motion of trajectory.csv (ramps and periods included); after its end the robot rests.
    duration = args.duration if getattr(args, "duration", None) is not None else motion.duration
    if not 0 < duration <= 3600:
        raise ConfigError(f"--duration must be in (0, 3600] s, got {duration!r}")
    data, truth_dict = simulate(robot, motion, truth, duration, measurement=measurement)
    data = data.replace(source=str(out))

    csv_text = measurement_to_csv_text(data)
    truth_file = truth_path_for(out)
    truth_dict["data_file"] = out.name
    atomic_write_text(truth_file, json.dumps(truth_dict, indent=2) + "\n")
    try:
        atomic_write_text(out, csv_text)
    except BaseException:
        truth_file.unlink(missing_ok=True)  # nothing half-written
        raise

    sim = truth_dict["simulation"]
    print(
        f"simulated {sim['duration']:.3g} s of '{robot.name}' at {sim['rate_hz']:g} Hz: "
        f"{sim['samples']} samples in {sim['wall_time_s']:.2f} s wall time"
    )
    print("tracking error RMS [mrad]: " + ", ".join(
        f"{j} {1e3 * e:.3g}" for j, e in sim["tracking_error_rms"].items()))
    recorded = {"joint_torque": "tau", "base_wrench": "wrench", "both": "tau and wrench"}[measurement]
    print(f"wrote {out} ({recorded} columns) and {truth_file}")
    return 0
