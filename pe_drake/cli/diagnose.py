"""``pe-drake diagnose``: the face of :func:`pe_drake.diagnosis.diagnose`."""

from __future__ import annotations

import math
from pathlib import Path

from pe_drake.cli.common import config_from_args, export_hint, read_log_from_args, robot_from_args
from pe_drake.diagnosis import DiagnosisConfig, diagnose
from pe_drake.exceptions import ConfigError
from pe_drake.identification import load_identified, model_method, unapplied_effects


def diagnose_command(args) -> int:
    """``pe-drake diagnose``: writes diagnosis.json, report.md, figures and the augmented model."""
    out = Path(args.out)  # checked and locked by main() before any work
    fraction = getattr(args, "held_out_fraction", None)
    if fraction is not None and not (math.isfinite(fraction) and 0.05 <= fraction <= 0.8):
        raise ConfigError(f"--held-out-fraction must be from 0.05 to 0.8, got {fraction:g}")
    settings = config_from_args(args)
    config = DiagnosisConfig(max_gap_s=settings.data.max_gap_s, **({} if fraction is None else {"holdout_fraction": fraction}))
    robot = robot_from_args(args, settings)
    data = read_log_from_args(args, robot, settings)
    validation = read_log_from_args(args, robot, settings, args.validation) if getattr(args, "validation", None) else None
    prior = load_identified(args.model, robot) if getattr(args, "model", None) else None  # as validate reads it
    print(f"robot {robot.name}: {robot.n} joints ({', '.join(robot.joint_names)})", flush=True)
    if prior is not None:
        print(f"a-priori model: {args.model} ({model_method(prior)})", flush=True)
        for note in unapplied_effects(prior):
            print(f"note: {note}", flush=True)
    result = diagnose(robot, data, validation, config, prior=prior, progress=lambda s: print(s, flush=True))
    written = result.write(out)
    print(f"wrote {', '.join(written)}")
    if not any(Path(w).name == "augmented_model.urdf" for w in written):  # identify says it too (issue 37)
        print(f"note: augmented_model.urdf not written: model export writes URDF files and '{Path(robot.model_path).name}' "
              "is not one; augmented_model.json and augmented_effects.yaml hold the augmented model (load the robot "
              "from a URDF to get the file)")
    if any(Path(w).name == "augmented_model.json" for w in written):
        print(export_hint(out / "augmented_model.json", args.robot, getattr(args, "config", None)))
    return 0
