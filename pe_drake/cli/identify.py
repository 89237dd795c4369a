"""``pe-drake identify`` and ``pe-drake validate``: the faces of
:func:`pe_drake.identification.identify_model` and :func:`pe_drake.identification.validate_model`."""

from __future__ import annotations

import argparse
from pathlib import Path

from pe_drake.cli.common import config_from_args, export_hint, measurement_from_args, read_log_from_args, robot_from_args
from pe_drake.export import is_simulator_model, validate_exported
from pe_drake.identification import (
    IdentifyOptions,
    TimeWindow,
    ValidateOptions,
    identify_model,
    load_identified,
    unapplied_effects,
    validate_model,
)
from pe_drake.output_paths import check_output_file


def identify_command(args: argparse.Namespace) -> int:
    """Runs ``pe-drake identify``: identified.json, model.urdf (when physically valid),
    residual plot; nothing is written on error."""
    out = Path(args.out)  # checked and locked by main() before any work
    config = config_from_args(args)
    options = IdentifyOptions.from_config(
        config, method=args.method, measurement=measurement_from_args(args, config), cutoff_hz=args.cutoff,
        trajectory=getattr(args, "trajectory", None), filtering=not getattr(args, "no_filter", False),
        drive_terms=getattr(args, "drive_terms", None), window=_window(args), rest=getattr(args, "rest", None))
    robot = robot_from_args(args, config)
    model = identify_model(robot, read_log_from_args(args, robot, config), options)
    for line in model.summary_lines():
        print(line, flush=True)
    written = model.write(out, progress=print)  # the note on model.urdf, if any
    print(f"wrote {out}/" + ", ".join(Path(p).name for p in written))
    print(export_hint(out / "identified.json", args.robot, getattr(args, "config", None)))
    return 0


def validate_command(args: argparse.Namespace) -> int:
    """Runs ``pe-drake validate``: per-channel RMS and relative error on another run."""
    if args.json:  # before any work
        check_output_file(args.json, "--json", (".json",))
    if args.plot:
        check_output_file(args.plot, "--plot", (".png", ".pdf", ".svg"))
    config = config_from_args(args)
    robot = robot_from_args(args, config)
    options = ValidateOptions(measurement_from_args(args, config), getattr(args, "cutoff", None), config.data.max_gap_s,
                              _window(args), filtering=not args.no_filter)
    if is_simulator_model(args.model):  # an exported model.xml/.urdf/.sdf: its simulator predicts
        report = validate_exported(robot, args.model, read_log_from_args(args, robot, config), options)
    else:
        model = load_identified(args.model, robot)  # identified.json or the diagnosis's augmented_model.json
        for note in unapplied_effects(model):
            print(f"note: {note}")
        report = validate_model(robot, model, read_log_from_args(args, robot, config), options)
    for line in [f"note: {n}" for n in report.notes] + report.summary_lines():
        print(line)
    written = report.write(Path(), json_name=args.json, plot_name=args.plot, model=args.model, data=args.data)
    for path in written:
        print(f"wrote {path}")
    return 0


def _window(args: argparse.Namespace) -> TimeWindow | None:
    text = getattr(args, "window", None)
    return None if text is None else TimeWindow.parse(text)
