"""``pe-drake export``: the face of :func:`pe_drake.export.model_export.export_model`."""

from __future__ import annotations

import argparse
from pathlib import Path

from pe_drake.cli.common import config_from_args, read_log_from_args, robot_from_args
from pe_drake.export import FORMATS, ExportOptions, export_model
from pe_drake.identification import TimeWindow
from pe_drake.output_paths import check_output_file


def export_command(args: argparse.Namespace) -> int:
    """Runs ``pe-drake export``: one file, checked, written whole or not at all."""
    options = ExportOptions(args.to, bandwidth_hz=args.bandwidth, damping_ratio=args.damping_ratio,
                            sigma_k=args.sigma_k, samples=args.samples, seed=args.seed,
                            window=None if args.window is None else TimeWindow.parse(args.window),
                            meshdir="" if args.no_meshes or args.to != "mjcf" else f"{Path(args.out).stem}_meshes")
    out = check_output_file(args.out, "--out", (FORMATS[args.to],))  # before any work
    config = config_from_args(args)
    robot = robot_from_args(args, config)
    held_out = read_log_from_args(args, robot, config) if args.data else None
    result = export_model(robot, args.model, options, held_out=held_out, progress=lambda line: print(line, flush=True))
    for line in result.summary_lines():
        print(line)
    path, *meshes = result.write(out.parent, name=out.name)
    print(f"wrote {path}")
    for folder in meshes:
        print(f"wrote {folder}/ ({len(result.meshes)} meshes)")
    return 0
