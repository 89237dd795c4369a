"""The paper's experiment (Ayusawa et al., ICRA 2017, section IV) on the Unitree G1.

The paper optimizes three exciting motions of HRP-4's 14 arm joints one after the other
(section IV-B): motion 1 without prior data (C0 = O in Eq. 41), motion i with the regressors
of motions 1..i-1 as C0. Table I lists cond(C^(i)) of each motion alone and cond of the
concatenated C after each motion; Table II the same for the conventional method of
reference [16]: random motions that satisfy the physical conditions, selected greedily.

Here the robot is G1 (models/g1.yaml): 14 arm joints, legs and waist locked, pelvis welded;
N = 10, ω = π/4 (period 8 s), T = 40 cost samples 0.2 s apart, K = 400 constraint samples
0.02 s apart, joint limits (Eq. 51), balance within r = 1 cm (Eq. 52), capsule
self-collision with a 2 cm margin (Eq. 53). The baseline uses the same robot, Fourier
series, samples and constraints: rejection sampling of random coefficients at a few
amplitudes (:mod:`pe_drake.excitation.baseline`), then greedy selection of 3.

    python examples/humanoid_g1_arms.py --out results/g1_tables            # ~7 min on 2 cores
    python examples/humanoid_g1_arms.py --quick --out /tmp/g1_quick        # smoke test, < 1 min
    python examples/humanoid_g1_arms.py --starts 16 --workers 16 --executor ray --ray-address HEAD:6379

Each motion: 2 starts solved in 2 worker processes (IPOPT ≤ 150 iterations each), the lower
cond kept; ``--executor ray`` runs the starts and the baseline's draws on a Ray cluster
(README, "Running on a cluster"). Motion 1 starts from 2 seeded random points; motions 2 and 3 from one random point
and one warm start, the earlier motion with the lowest cond on the current prior
(:func:`pe_drake.excitation.sequential.optimize_sequence`). Progress lines go to stdout; the tables are
printed at the end.

Outputs in --out: tables.md, tables.json, motion_<i>/trajectory.json (optimized) and
baseline_<i>/trajectory.json (selected random motions); view one with
``pe-drake view results/g1_tables/motion_1/trajectory.json``.

cond values are not comparable between robots (they depend on the masses, lengths and units
of the base parameters), so the paper's HRP-4 figures are shown for reference; what carries
over is the ratio between the random baseline and the optimization.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from pathlib import Path

from pe_drake.config import CRITERIA
from pe_drake.exceptions import ConfigError
from pe_drake.excitation.sequential_study import FULL, QUICK, StudyOptions, run_sequential_study


def _number(kind: type, what: str, ok):
    """An argparse type: ``kind(text)`` that must pass ``ok`` (e.g. be positive)."""

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, got '{text}'") from None
        if not math.isfinite(value) or not ok(value):
            raise argparse.ArgumentTypeError(f"expected {what}, got {text}")
        return value

    return parse


_positive_int = _number(int, "a positive integer", lambda v: v >= 1)
_positive_float = _number(float, "a positive number", lambda v: v > 0)
_nonnegative_float = _number(float, "a number >= 0", lambda v: v >= 0)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="humanoid_g1_arms.py",
        description="Tables I and II of Ayusawa et al. (ICRA 2017) on the Unitree G1's 14 arm joints.",
    )
    p.add_argument("--out", default="results/g1_tables", help="output folder (default: %(default)s)")
    p.add_argument("--config", help="YAML file overriding models/g1.yaml (robot, excitation, solver)")
    p.add_argument("--motions", type=_positive_int, default=3, help="sequential motions (default: 3)")
    p.add_argument("--starts", type=_positive_int, help=f"random starts per motion (default: {FULL['starts']}, quick 1)")
    p.add_argument("--workers", type=_positive_int, help=f"processes (default: {FULL['workers']}, quick 1)")
    p.add_argument("--executor", choices=("local", "ray"), default="local", help="where the starts and draws run")
    p.add_argument("--ray-address", default="", metavar="ADDR", help="join this Ray cluster (--executor ray)")
    p.add_argument(
        "--max-iterations",
        type=_positive_int,
        help=f"IPOPT iterations per start (default: {FULL['max_iterations']}, quick {QUICK['max_iterations']})",
    )
    p.add_argument("--max-time", type=_nonnegative_float, default=0.0, help="wall-time limit per start [s] (0: none)")
    p.add_argument("--criterion", choices=CRITERIA, help="criterion (default: the config's, soft_cond)")
    p.add_argument("--amplitude", type=_positive_float, help="scale of the random initial points [rad]")
    p.add_argument(
        "--candidates",
        type=_positive_int,
        help=f"accepted random motions per baseline amplitude (default: {FULL['candidates']}, quick {QUICK['candidates']})",
    )
    p.add_argument(
        "--baseline-amplitudes",
        type=_positive_float,
        nargs="+",
        metavar="RAD",
        help="amplitudes of the random baseline motions [rad] (default: "
        + " ".join(str(a) for a in FULL["baseline_amplitudes"])
        + ")",
    )
    p.add_argument("--seed", type=int, default=0, help="first seed (default: 0)")
    p.add_argument("--quick", action="store_true", help="a much smaller run (few iterations and candidates, 1 start)")
    p.add_argument("--quiet", action="store_true", help="print only the tables")
    return p


def parse_args(argv: Sequence[str] | None = None) -> tuple[StudyOptions, Path, bool]:
    """Command line → (study options, output folder, quiet); bad values exit with status 2."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        options = _options(args, QUICK if args.quick else FULL)
    except ConfigError as err:  # e.g. too few candidates for the motions
        parser.error(str(err))
    out = Path(args.out)
    if options.config is not None and not options.config.is_file():
        parser.error(f"--config: file '{options.config}' does not exist")
    if out.exists() and not out.is_dir():
        parser.error(f"--out: '{out}' exists and is not a folder")
    return options, out, args.quiet


def _options(args: argparse.Namespace, defaults: dict) -> StudyOptions:
    return StudyOptions(
        config=Path(args.config) if args.config else None,
        motions=args.motions,
        starts=args.starts or defaults["starts"],
        workers=args.workers or defaults["workers"],
        executor="ray" if args.ray_address else args.executor,
        ray_address=args.ray_address,
        max_iterations=args.max_iterations or defaults.get("max_iterations"),
        max_time=args.max_time,
        criterion=args.criterion,
        amplitude=args.amplitude,
        candidates=args.candidates or defaults["candidates"],
        baseline_amplitudes=tuple(args.baseline_amplitudes or defaults["baseline_amplitudes"]),
        seed=args.seed,
        quick=args.quick,
    )


def _say(text: str) -> None:
    print(text, flush=True)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns 0 on success, 1 if a motion violates a constraint, 2 on bad input."""
    import logging

    import pydrake.common  # noqa: F401  (pydrake resets the logger level at import)

    from pe_drake.exceptions import InfeasibleError, PeDrakeError
    from pe_drake.threads import single_threaded_blas

    logging.getLogger("drake").setLevel(logging.ERROR)  # IPOPT limits: in our own messages
    options, out, quiet = parse_args(argv)
    try:
        with single_threaded_blas():
            study = run_sequential_study(options, say=None if quiet else _say)
            files = study.write(out)
    except ConfigError as err:
        print(f"humanoid_g1_arms.py: error: {err}", file=sys.stderr)
        return 2
    except InfeasibleError as err:
        print(f"humanoid_g1_arms.py: no feasible motion: {err}", file=sys.stderr)
        return 1
    except PeDrakeError as err:  # e.g. WorkerError: a worker died
        print(f"humanoid_g1_arms.py: {type(err).__name__}: {err}", file=sys.stderr)
        return 1
    print(study.console(), flush=True)
    print(f"wrote {out}/tables.md, tables.json and " + ", ".join(files), flush=True)
    return 0 if study.success else 1


if __name__ == "__main__":
    sys.exit(main())
