"""``pe-drake simulate``: a measured run of a perturbed 'true' robot, written as CSV + truth JSON."""

from __future__ import annotations

import json
from pathlib import Path

from pe_drake.cli.common import robot_from_args
from pe_drake.exceptions import ConfigError, DataError
from pe_drake.excitation.trajectory_file import load_trajectory
from pe_drake.identification.measurements import measurement_to_csv_text
from pe_drake.identification.simulation import simulate, truth_path_for
from pe_drake.identification.truth import load_truth
from pe_drake.io_utils import atomic_write_text


def simulate_command(args) -> int:
    """``pe-drake simulate``: writes the CSV and its ``.truth.json``; prints a summary."""
    out = Path(args.out)
    if out.is_dir():
        raise ConfigError(f"--out '{out}' is a folder; give the CSV file to write")
    truth = load_truth(args.truth)
    robot = robot_from_args(args)
    trajectory, data = load_trajectory(args.trajectory)
    if list(data["joints"]) != list(robot.joint_names):
        raise DataError(
            f"trajectory joints {', '.join(data['joints'])} differ from robot '{robot.name}''s "
            f"excited joints {', '.join(robot.joint_names)}",
            file=str(args.trajectory),
        )
    duration = args.duration if getattr(args, "duration", None) is not None else data.get("duration")
    measurement, truth_dict = simulate(robot, trajectory, truth, duration)
    measurement = measurement.replace(source=str(out))

    csv_text = measurement_to_csv_text(measurement)
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
    print(f"wrote {out} and {truth_file}")
    return 0
