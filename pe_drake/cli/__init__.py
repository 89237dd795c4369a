"""Command line: ``pe-drake optimize | view | simulate | identify | validate | diagnose | export``.

Each sub-command's arguments are parsed here, then its ``*_command(args) -> int`` is imported
lazily and run. Every :class:`~pe_drake.exceptions.PeDrakeError` becomes one line and exit code 2.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import sys

from pe_drake import __version__
from pe_drake.config import CRITERIA, DATA_FORMATS, EFFORT_KINDS, MEASUREMENTS
from pe_drake.exceptions import OutputWriteError, PeDrakeError
from pe_drake.io_utils import Terminated, describe_write_error, terminated_as_exception
from pe_drake.output_paths import check_output_dir
from pe_drake.output_set import output_lock
from pe_drake.threads import single_threaded_blas

#: The commands whose --out is a folder of pe_drake's outputs (locked while they run).
_FOLDER_COMMANDS = ("optimize", "identify", "diagnose")


def add_robot_arguments(parser: argparse.ArgumentParser) -> None:
    """``--robot``, ``--config`` and ``--trust-xacro``: what every command loading a robot takes."""
    parser.add_argument("--robot", required=True, help="built-in name (panda, ur5, g1) or URDF/SDF path")
    parser.add_argument("--config", help="YAML config overriding the robot's defaults")
    add_trust_xacro_argument(parser)


def add_trust_xacro_argument(parser: argparse.ArgumentParser) -> None:
    """``--trust-xacro``: expand a xacro model with xacro's full Python (a xacro is a program)."""
    parser.add_argument("--trust-xacro", action="store_true",
                        help="run a .xacro model with xacro's full Python ($(eval) builtins, load_yaml, $(env)); "
                             "only for files whose author you trust (default: those are refused)")


def add_measurement_argument(parser: argparse.ArgumentParser, what: str) -> None:
    """``--measurement joint_torque | base_wrench | both``; overrides the config's."""
    parser.add_argument("--measurement", choices=MEASUREMENTS,
                        help=f"{what} (default: the config's excitation.measurement, joint_torque)")


def add_log_arguments(parser: argparse.ArgumentParser) -> None:
    """``--format``, ``--topic``, ``--effort``: how a measured log is read; override ``data.*``."""
    parser.add_argument("--format", choices=DATA_FORMATS, help="format of --data (default: data.format, auto)")
    parser.add_argument("--topic", help="JointState topic of a ROS 2 bag (default: the only one)")
    parser.add_argument("--effort", choices=EFFORT_KINDS,
                        help="what a bag's effort holds: torque [N·m] or current [A] (robot.drive_gains)")


def add_window_argument(parser: argparse.ArgumentParser, what: str) -> None:
    """``--window START,END``: the part of the run used, cut after the whole run is filtered."""
    parser.add_argument("--window", metavar="START,END",
                        help=f"only the samples from START to END [s, the file's time] are {what}; either may be "
                             "empty (',14.7'); the whole run is filtered first, so the cut has no filter edge "
                             "(diagnose's training/held-out times reproduce its split)")


def build_parser() -> argparse.ArgumentParser:
    description = "Exciting trajectories, identification and model diagnosis on Drake."
    parser = argparse.ArgumentParser(prog="pe-drake", description=description)
    parser.add_argument("--version", action="version", version=f"pe_drake {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    _add_trajectory_commands(sub)
    _add_identification_commands(sub)
    return parser


def _add_trajectory_commands(sub) -> None:
    """``optimize``, ``view`` and ``simulate``: making, showing and running a trajectory."""
    p = sub.add_parser("optimize", help="optimize an exciting trajectory (min cond of the regressor)")
    add_robot_arguments(p)
    p.add_argument("--solver", choices=["ipopt", "nlopt"], help="optimizer (default: from config, ipopt)")
    p.add_argument("--criterion", choices=CRITERIA, help="excitation criterion (default: the "
                   "config's, soft_cond: a smooth bound of cond)")
    p.add_argument("--prior", action="append", default=[], metavar="TRAJECTORY_JSON",
                   help="earlier trajectory whose data is reused as C0 (repeatable)")
    p.add_argument("--max-iterations", type=int, help="solver iteration limit")
    p.add_argument("--seed", type=int, help="seed of the random initial point (start k: seed + k)")
    p.add_argument("--starts", type=int, help="random starts; the feasible one with the lowest criterion is kept "
                   "(default: config parallel.starts, 1)")
    p.add_argument("--workers", type=int, help="starts solved at once (default: the cores available, at most --starts)")
    p.add_argument("--executor", choices=["local", "ray"], help="where the starts run: local processes or a Ray "
                   "cluster (default: config parallel.executor, local)")
    p.add_argument("--ray-address", metavar="ADDR", help="join this Ray cluster (default: ray.init()'s: the cluster "
                   "started here with `ray start`, else a new local instance)")
    add_measurement_argument(p, "rows of C: joint torques, the ground wrench (foot F/T sensors), or both")
    p.add_argument("--drive-terms", choices=["none", "friction", "all"],
                   help="identify's friction, offset (and armature) columns in C too, their expected σ reported "
                        "(default: the config's excitation.drive_terms, none)")
    p.add_argument("--csv-rate", type=float, default=1000.0, help="rate of trajectory.csv [Hz]")
    p.add_argument("--periods", type=int,
                   help="periods of the path in trajectory.csv (default: excitation.periods, 1)")
    p.add_argument("--no-ramp", action="store_true",
                   help="no ramp from/to rest: trajectory.csv then starts at full speed (unsafe on hardware)")
    p.add_argument("--no-html", action="store_true", help="do not write the Meshcat HTML playback")
    p.add_argument("--allow-unchecked", action="store_true",
                   help="write the trajectory although parts of the robot could not be checked for collision "
                        "(exit 0; the list stays in report.json 'unchecked')")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    p.add_argument("--payload", metavar="LINK", help="a short motion for a payload on LINK alone")
    p.add_argument("--out", required=True, help="output folder")

    p = sub.add_parser("view", help="play a trajectory in Meshcat")
    p.add_argument("trajectory", help="trajectory.json")
    p.add_argument("--robot", help="override the robot named in the trajectory file")
    p.add_argument("--config", help="YAML config of the robot")
    add_trust_xacro_argument(p)
    p.add_argument("--html", help="write a self-contained HTML playback here and exit")
    p.add_argument("--no-capsules", action="store_true", help="hide the collision capsules")
    p.add_argument("--rate", type=float, default=30.0, help="frames per second")
    p.add_argument("--host", default="localhost",
                   help="interface Meshcat listens on (default localhost; '*' for every interface)")

    p = sub.add_parser("simulate", help="simulate a measured run on a perturbed 'true' robot")
    add_robot_arguments(p)
    p.add_argument("--trajectory", required=True, help="trajectory.json to track")
    p.add_argument("--truth", help="TRUTH.yaml: perturbation, effects, noise (on top of --model's; needed without it)")
    p.add_argument("--model", help="identified.json or augmented_model.json: simulate that model (its parameters, "
                   "friction, armature, offsets) instead of the URDF's")
    p.add_argument("--out", required=True, help="output CSV")
    p.add_argument("--duration", type=float,
                   help="simulated time [s] (default: the whole motion of trajectory.csv, ramps included)")
    add_measurement_argument(p, "what the robot records: tau columns, wrench.* columns (the root link's weld reaction), or both")


def _add_identification_commands(sub) -> None:
    """``identify``, ``validate`` and ``diagnose``: from measured data to a model and its faults."""
    p = sub.add_parser("identify", help="identify the base parameters from measured data")
    add_robot_arguments(p)
    p.add_argument("--data", required=True, action="append",
                   help="measurement CSV, ROS 2 bag (folder, .db3, .mcap) or RTDE log (repeatable with --payload: "
                        "the loaded runs)")
    add_log_arguments(p)
    p.add_argument("--method", choices=["ols", "wls", "physical"], default="wls",
                   help="wls (default: per-joint noise weights), ols (Eq. 4, unweighted), or physical (every "
                        "link physically consistent, each rigid group of welded links one body; weighted by wls's "
                        "per-joint noise weights; writes model.urdf)")
    p.add_argument("--cutoff", type=float, help="low-pass cut-off [Hz] (default: from --trajectory or the data)")
    p.add_argument("--trajectory", help="trajectory.json that was run (its harmonics set the cut-off)")
    add_window_argument(p, "fitted")
    p.add_argument("--no-filter", action="store_true",
                   help="use the data as it is (exact data with v.* and vdot.* columns)")
    add_measurement_argument(p, "channels to identify from: joint torques, the ground wrench alone, or both")
    p.add_argument("--drive-terms", choices=["none", "friction", "all"],
                   help="joint friction (Coulomb + viscous), torque offsets and, with 'all', the armature where "
                        "separable (default: the config's identification.drive_terms, all)")
    p.add_argument("--rest", choices=["auto", "keep", "exclude"],
                   help="the torque rows of a joint at rest (its holding friction is unknown): kept out of the fit "
                        "if cross-validation says so (auto, the default), kept, or kept out")
    p.add_argument("--payload", metavar="LINK", help="identify a payload on LINK, the arm frozen")
    p.add_argument("--unloaded", action="append", metavar="CSV", help="--payload: a run of the same motion "
                   "without the payload (repeatable)")
    p.add_argument("--model", help="--payload: the arm's identified.json (default: the URDF's parameters)")
    p.add_argument("--flange", help="--payload: the vendor flange link (default: panda_link8, tool0, ...)")
    p.add_argument("--payload-box", metavar="CX,CY,CZ,SX,SY,SZ",
                   help="--payload: the object's box in LINK's frame [m] (centre, edge lengths)")
    p.add_argument("--out", required=True, help="output folder")

    p = sub.add_parser("validate", help="predict torques of another run with an identified model")
    add_robot_arguments(p)
    p.add_argument("--model", required=True, help="identified.json or diagnose's augmented_model.json; or an "
                   "exported model.xml (torques computed by MuJoCo), model.urdf or model.sdf (by Drake)")
    p.add_argument("--data", required=True, help="measurement CSV (or bag, RTDE log) of another run")
    add_log_arguments(p)
    p.add_argument("--cutoff", type=float, help="low-pass cut-off [Hz] (default: from the data)")
    add_window_argument(p, "predicted")
    p.add_argument("--no-filter", action="store_true",
                   help="predict the torques as recorded, unfiltered (needs v.* and vdot.* columns)")
    p.add_argument("--json", help="write per-joint errors here")
    p.add_argument("--plot", help="write measured vs predicted torque plot here (PNG)")
    add_measurement_argument(p, "channels to predict (from any identified model): joint torques, the ground wrench, or both")

    p = sub.add_parser("diagnose", help="name the effects missing from the model")
    add_robot_arguments(p)
    p.add_argument("--data", required=True, help="measurement CSV, ROS 2 bag (folder, .db3, .mcap) or RTDE log")
    add_log_arguments(p)
    p.add_argument("--validation", help="held-out CSV (default: a held-out part of --data)")
    p.add_argument("--held-out-fraction", type=float, default=None,
                   help="fraction of --data held out at its end when no --validation is given "
                        "(default 0.3, from 0.05 to 0.8)")
    p.add_argument("--model", help="start from an earlier model (identified.json of identify, or augmented_model.json "
                                   "of diagnose) as the a-priori model (default: the URDF's)")
    p.add_argument("--out", required=True, help="output folder")
    _add_export_command(sub)


def _add_export_command(sub) -> None:
    """``export``: the identified robot in a simulator's or controller's format."""
    p = sub.add_parser("export", help="write the identified robot for MuJoCo, Drake/ROS or a controller")
    p.add_argument("model", nargs="?", help="identified.json (any method) or augmented_model.json "
                   "(default: the robot's own model file, the CAD model)")
    add_robot_arguments(p)
    p.add_argument("--to", required=True, choices=["mjcf", "urdf", "sdf", "feedforward", "gains"],
                   help="mjcf (MuJoCo .xml), urdf or sdf (Drake, ROS), feedforward (friction YAML), gains "
                        "(PD gains, effective inertia, randomization ranges YAML)")
    p.add_argument("--out", required=True, help="output file (.xml, .urdf, .sdf, .yaml)")
    p.add_argument("--data", help="a held-out run: the projection's and the feed-forward's effect on it, the "
                                  "postures of the gains")
    add_log_arguments(p)
    add_window_argument(p, "used from --data")
    p.add_argument("--bandwidth", type=float, default=10.0, help="gains: closed-loop bandwidth [Hz] (default 10)")
    p.add_argument("--damping-ratio", type=float, default=1.0, help="gains: damping ratio ζ (default 1)")
    p.add_argument("--sigma-k", type=float, default=2.0, help="gains: randomization ranges value ± k·σ (default 2)")
    p.add_argument("--samples", type=int, default=10, help="gains: consistent models drawn from σ (default 10)")
    p.add_argument("--seed", type=int, default=0, help="gains: seed of the draws")
    p.add_argument("--no-meshes", action="store_true",
                   help="mjcf: no visual geometry (default: the model's visuals, meshes in OUT_STEM_meshes/ beside it)")


def _folder_lock(args) -> contextlib.AbstractContextManager:
    """The output folder's lock for the whole run (a second run on it is refused at once, not
    after its solve)."""
    if args.command not in _FOLDER_COMMANDS:
        return contextlib.nullcontext()
    return output_lock(check_output_dir(args.out))


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    # pe_drake.cli.<command>.<command>_command; validate lives with identify.
    module_name = "pe_drake.cli." + ("identify" if args.command == "validate" else args.command)
    function_name = f"{args.command}_command"
    if getattr(args, "payload", None) and args.command in ("optimize", "identify"):
        module_name, function_name = "pe_drake.cli.payload", f"payload_{args.command}_command"
    elif args.command == "identify":
        if len(args.data) > 1:
            parser.error("identify: --data is given once (several only with --payload)")
        args.data = args.data[0]
    try:
        function = getattr(importlib.import_module(module_name), function_name)
        with terminated_as_exception(), single_threaded_blas(), _folder_lock(args):
            return int(function(args) or 0)
    except OutputWriteError as err:  # not the user's input: a full disk, a quota
        print(f"pe-drake {args.command}: error: {err}", file=sys.stderr)
        return 1
    except PeDrakeError as err:
        print(f"pe-drake {args.command}: error: {err}", file=sys.stderr)
        return 2
    except OSError as err:
        print(f"pe-drake {args.command}: error: {describe_write_error(err)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"pe-drake {args.command}: interrupted", file=sys.stderr)
        return 130
    except Terminated:  # SIGTERM: the outputs were cleaned up as for Ctrl-C
        print(f"pe-drake {args.command}: terminated (SIGTERM); nothing half-written was left", file=sys.stderr)
        return 143


if __name__ == "__main__":
    sys.exit(main())
