"""``pe-drake diagnose``: name the effects missing from the model of a measured run."""

from __future__ import annotations

import math
from pathlib import Path

from pe_drake.cli.common import config_from_args, print_notes, read_log_from_args, robot_from_args
from pe_drake.diagnosis import DiagnosisConfig, diagnose, write_outputs
from pe_drake.exceptions import ConfigError
from pe_drake.identification.data_checks import check_against_model
from pe_drake.identification.estimators import prepare_measurement
from pe_drake.identification.gaps import longest_segment
from pe_drake.io_utils import staged_output_dir
from pe_drake.output_paths import DIAGNOSE_OUTPUTS, check_output_dir, remove_stale_outputs


def diagnose_command(args) -> int:
    """``pe-drake diagnose``: writes diagnosis.json, report.md, figures and the augmented model."""
    out = check_output_dir(args.out)  # before any work
    fraction = getattr(args, "held_out_fraction", None)
    if fraction is not None and not (math.isfinite(fraction) and 0.05 <= fraction <= 0.8):
        raise ConfigError(f"--held-out-fraction must be from 0.05 to 0.8, got {fraction:g}")
    config = DiagnosisConfig() if fraction is None else DiagnosisConfig(holdout_fraction=fraction)
    settings = config_from_args(args)
    robot = robot_from_args(args, settings)
    gap = settings.data.max_gap_s  # holes up to it interpolated; a paused run: its longest segment
    data = longest_segment(read_log_from_args(args, robot, settings), gap)
    validation = (longest_segment(read_log_from_args(args, robot, settings, args.validation), gap)
                  if getattr(args, "validation", None) else None)
    for run in (data, validation):
        if run is not None:
            print_notes(run)
    for run in (data, validation):  # units, gaps, degrees, sign flips: before any work
        if run is not None:
            check_against_model(robot, prepare_measurement(robot, run, max_gap_s=gap))
    print(f"robot {robot.name}: {robot.n} joints ({', '.join(robot.joint_names)})", flush=True)
    result = diagnose(robot, data, validation, config, progress=lambda s: print(s, flush=True))
    with staged_output_dir(out) as tmp:
        written = write_outputs(tmp, robot, result)
    remove_stale_outputs(out, DIAGNOSE_OUTPUTS, [Path(w).name for w in written])  # e.g. an old unexplained.png
    print(f"wrote {', '.join(str(out / Path(w).name) for w in written)}")
    return 0
