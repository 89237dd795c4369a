"""``pe-drake diagnose``: name the effects missing from the model of a measured run."""

from __future__ import annotations

from pathlib import Path

from pe_drake.cli.common import robot_from_args
from pe_drake.diagnosis import diagnose, write_outputs
from pe_drake.exceptions import ConfigError
from pe_drake.identification.measurements import read_measurement_csv
from pe_drake.io_utils import staged_output_dir


def diagnose_command(args) -> int:
    """``pe-drake diagnose``: writes diagnosis.json, report.md, figures and the augmented model."""
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out '{out}' exists and is not a folder")
    robot = robot_from_args(args)
    data = read_measurement_csv(args.data, robot)
    validation = read_measurement_csv(args.validation, robot) if getattr(args, "validation", None) else None
    print(f"robot {robot.name}: {robot.n} joints ({', '.join(robot.joint_names)})", flush=True)
    result = diagnose(robot, data, validation, progress=lambda s: print(s, flush=True))
    with staged_output_dir(out) as tmp:
        written = write_outputs(tmp, robot, result)
    print(f"wrote {', '.join(str(out / Path(w).name) for w in written)}")
    return 0
