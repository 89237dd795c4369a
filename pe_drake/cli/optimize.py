"""``pe-drake optimize``: the face of :func:`pe_drake.excitation.optimize_motion`."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from pe_drake.cli.common import config_from_args
from pe_drake.config import Config, validate_config
from pe_drake.exceptions import ConfigError
from pe_drake.excitation import check_csv_size, optimize_motion
from pe_drake.multibody import robot_display_name
from pe_drake.viewer import write_plan_playback


def apply_arguments(config: Config, args: argparse.Namespace) -> Config:
    """The config with the command's flags on top (a new config; ``config`` is not changed)."""
    if args.workers is not None and args.workers < 1:
        raise ConfigError(f"--workers must be a positive integer, got {args.workers}")
    if args.seed is not None and not 0 <= args.seed < 2**32:
        raise ConfigError(f"--seed must be an integer from 0 to 2^32 - 1, got {args.seed}")
    if args.periods is not None and not 1 <= args.periods <= 1000:
        raise ConfigError(f"--periods must be an integer from 1 to 1000, got {args.periods}")
    given = lambda **kw: {k: v for k, v in kw.items() if v is not None}  # noqa: E731
    solver = given(name=args.solver or None, max_iterations=args.max_iterations, verbose=False if args.quiet else None)
    excitation = given(criterion=args.criterion or None, seed=args.seed, measurement=args.measurement or None,
                       periods=args.periods, ramp=False if args.no_ramp else None, drive_terms=args.drive_terms)
    executor = "ray" if args.ray_address and not args.executor else args.executor or None
    parallel = given(starts=args.starts, workers=args.workers, executor=executor, address=args.ray_address or None)
    return validate_config(dataclasses.replace(
        config,
        solver=dataclasses.replace(config.solver, **solver),
        excitation=dataclasses.replace(config.excitation, **excitation),
        parallel=dataclasses.replace(config.parallel, **parallel),
    ))


def optimize_command(args: argparse.Namespace) -> int:
    """Runs ``pe-drake optimize``; returns 0 on success, 1 if no valid trajectory was found."""
    out = Path(args.out)  # checked and locked by main() before any work
    config = config_from_args(args, lambda c: apply_arguments(c, args))
    check_csv_size(config, args.csv_rate)
    say = (lambda *a: None) if args.quiet else (lambda *a: print(*a, flush=True))
    plan = optimize_motion(config, priors=args.prior, progress=say, name=robot_display_name(args.robot),
                           allow_unchecked=args.allow_unchecked)
    written = plan.write(out, csv_rate=args.csv_rate, playback=None if args.no_html else write_plan_playback,
                         progress=say)
    if plan.refusal is not None:
        print(f"pe-drake optimize: not valid for hardware: {plan.refusal}. Only {', '.join(written)} was written.",
              file=sys.stderr)
        return 1
    if not plan.success:
        print(f"pe-drake optimize: no valid trajectory: {plan.result.message}. Only {', '.join(written)} was "
              "written. Try more iterations (--max-iterations), more starts (--starts), another seed (--seed), "
              "or looser margins.", file=sys.stderr)
        return 1
    say(f"wrote {out}/" + ", ".join(Path(p).name for p in written))
    return 0
