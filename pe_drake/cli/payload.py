"""``pe-drake optimize --payload`` and ``pe-drake identify --payload``: the faces of
:func:`pe_drake.excitation.optimize_payload` and :func:`pe_drake.identification.identify_payload_runs`."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from pe_drake.cli.common import config_from_args, robot_from_args
from pe_drake.excitation import optimize_payload, write_payload_plan
from pe_drake.identification import identify_payload_runs, parse_payload_box


def payload_optimize_command(args: argparse.Namespace) -> int:
    """Optimizes a payload motion: trajectory.json (with ``payload_link``), trajectory.csv, report.json."""
    out = Path(args.out)  # checked and locked by main()
    say = (lambda *a: None) if args.quiet else (lambda *a: print(*a, flush=True))
    config = config_from_args(args)
    robot = robot_from_args(args, config)
    plan = optimize_payload(config, robot, args.payload, seed=args.seed, criterion=args.criterion or None,
                            max_iterations=args.max_iterations,
                            allow_unchecked=getattr(args, "allow_unchecked", False), progress=say)
    written = write_payload_plan(plan, out, robot, args.csv_rate)
    say(f"wrote {args.out}/" + ", ".join(written))
    return 0


def payload_identify_command(args: argparse.Namespace) -> int:
    """Identifies a payload: payload.json (with the vendor formats) and model_with_payload.urdf."""
    out = Path(args.out)  # checked and locked by main()
    start = time.perf_counter()
    config = config_from_args(args)
    robot = robot_from_args(args, config)
    found = identify_payload_runs(robot, args.data, args.unloaded or [], args.payload, model=args.model,
                                  trajectory=args.trajectory, cutoff_hz=args.cutoff, filtering=not args.no_filter,
                                  box=parse_payload_box(args.payload_box), flange=args.flange)
    for line in found.summary_lines():
        print(line)
    written = found.write(out)
    print(f"wrote {args.out}/" + ", ".join(written) + f" ({time.perf_counter() - start:.1f} s)")
    return 0
