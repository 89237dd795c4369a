"""``pe-drake simulate``: the face of :func:`pe_drake.simulation.simulate_run`."""

from __future__ import annotations

from pe_drake.cli.common import config_from_args, measurement_from_args, robot_from_args
from pe_drake.output_paths import check_output_file
from pe_drake.simulation import SimulateOptions, simulate_run


def simulate_command(args) -> int:
    """``pe-drake simulate``: writes the CSV and its ``.truth.json``; prints a summary."""
    out = check_output_file(args.out, "--out", (".csv",))  # before any work
    config = config_from_args(args)
    options = SimulateOptions(getattr(args, "truth", None), getattr(args, "model", None), getattr(args, "duration", None),
                              measurement_from_args(args, config))
    robot = robot_from_args(args, config, show_limit_notes=True)
    run = simulate_run(robot, args.trajectory, options, progress=lambda s: print(s, flush=True))
    csv, truth_file = run.write(out.parent, name=out.name)
    for line in run.summary_lines():
        print(line)
    print(f"wrote {csv} ({run.recorded} columns) and {truth_file}")
    return 0
