"""``python -m pe_drake.bench robots``: every arm and humanoid of example-robot-data through
the library's front doors, as a user bringing that robot would run it (issue 21).

For each robot: ``resolve_robot_config`` (the bench's caps on top) → ``Robot`` →
``optimize_motion`` (capped: ``--max-iterations``, one start, one period) → the written
trajectory.json checked at 1 kHz → ``simulate_run`` with hidden Coulomb and viscous friction
(:func:`hidden_friction`) → ``read_measurements`` → ``identify_model`` (WLS) → ``diagnose``
(did it name the hidden friction?). It prints one table row per robot as it finishes; a stage
that fails fills the row's ``note`` with its reason and the bench goes on.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import re
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from pe_drake.bench_models import dual_arm_lift, folding_arm, scara, textured_xacro, without_inertials
from pe_drake.diagnosis import diagnose
from pe_drake.excitation import optimize_motion
from pe_drake.excitation.ramp import check_written_motion
from pe_drake.excitation.trajectory_file import load_motion
from pe_drake.identification import IdentifyOptions, identify_model, read_measurements
from pe_drake.multibody.capsules import load_capsule_file
from pe_drake.multibody.packages import example_robot_data_dir
from pe_drake.multibody.registry import builtin_robots, resolve_robot_config
from pe_drake.multibody.robot import Robot
from pe_drake.simulation import SimulateOptions, simulate_run


@dataclasses.dataclass(frozen=True)
class BenchRobot:
    """One robot of the bench.

    Attributes:
        name: what ``--robots`` calls it.
        model: a path under example-robot-data's ``robots/``, a built-in name, or a model file.
        config: YAML text a user would write for it, put under the bench's caps.
        build: writes the model into the run's folder (then ``model`` is unused).
        simulate_with: writes the model the simulated run comes from, when not the model
            itself (a model without inertials is identified from a robot that has them).
    """

    name: str
    model: str
    config: str = ""
    build: Callable[[Path], Path] | None = None
    simulate_with: Callable[[Path], Path] | None = None


#: TIAGo is a mobile manipulator: its arm is excited, the wheels, torso lift and head locked.
_TIAGO_ARM = "robot:\n  joints: [" + ", ".join(f"arm_{k}_joint" for k in range(1, 8)) + "]\n"
#: Baxter's right arm; the head and the left arm locked at zero.
_BAXTER_RIGHT = "robot:\n  joints: [" + ", ".join(f"right_{j}" for j in ("s0", "s1", "e0", "e1", "w0", "w1", "w2")) + "]\n"

#: The arms and humanoids of example-robot-data, in the order they run (issue 21's first).
ROBOTS = (
    BenchRobot("ur3", "ur_description/urdf/ur3_robot.urdf"),
    BenchRobot("so101", "so_arm_description/urdf/so101.urdf"),
    BenchRobot("z1", "z1_description/urdf/z1.urdf"),
    BenchRobot("kinova", "kinova_description/robots/kinova.urdf"),  # a JACO2 j2s6s200
    BenchRobot("ur5", "ur_description/urdf/ur5_robot.urdf"),
    BenchRobot("ur10", "ur_description/urdf/ur10_robot.urdf"),
    BenchRobot("xarm7", "xarm_description/urdf/xarm7.urdf"),
    BenchRobot("panda_fingers", "panda_description/urdf/panda.urdf"),
    BenchRobot("tiago_arm", "tiago_description/robots/tiago_no_hand.urdf", _TIAGO_ARM),
    BenchRobot("talos", "talos_data/robots/talos_reduced.urdf"),
    BenchRobot("romeo", "romeo_description/urdf/romeo.urdf"),
    BenchRobot("icub", "icub_description/robots/icub_reduced.urdf"),
    BenchRobot("so100", "so_arm_description/urdf/so100.urdf"),
    BenchRobot("baxter_right", "baxter_description/urdf/baxter.urdf", _BAXTER_RIGHT),
    BenchRobot("panda", "panda"),  # the shipped configs: capsule files
    BenchRobot("ur5_config", "ur5"),
    BenchRobot("g1", "g1"),
    BenchRobot("simple_humanoid", "simple_humanoid_description/urdf/simple_humanoid.urdf"),
    # issue 37's kinds, built as text (pe_drake.bench_models): an SDF with a prismatic quill (a SCARA
    # on a table: no floor below its moving parts), a model without inertials, a two-arm torso on a lift,
    # an Interbotix-style textured xacro in its description package
    BenchRobot("scara_sdf", "", "environment: {floor: false}\n", build=functools.partial(scara, fmt="sdf")),
    BenchRobot("folding_no_inertials", "", build=lambda f: without_inertials(folding_arm(f, collision=True)[0], f),
               simulate_with=lambda f: folding_arm(f, collision=True)[0]),
    BenchRobot("dual_arm_lift", "", build=dual_arm_lift),
    BenchRobot("textured_xacro", "", build=textured_xacro),  # a description package's xacro, textured visuals
)

COLUMNS = ("robot", "loads", "mount", "capsules", "valid 1 kHz", "cond", "effect named", "s", "note")
#: Longest reason shown in a row [characters].
REASON_CHARS = 90


@dataclasses.dataclass(frozen=True)
class BenchOptions:
    """The caps of one bench run (None: the robot's config, the whole written motion)."""

    max_iterations: int = 60  # IPOPT iterations per robot
    max_time: float = 240.0  # IPOPT wall-time limit per robot [s]
    harmonics: int | None = None
    duration: float | None = None  # simulated [s]
    seed: int = 0  # the truth's (inertial error and noise)


@dataclasses.dataclass
class Row:
    """One robot's line of the table (``-``: the stage was not reached)."""

    robot: str
    loads: str = "-"
    mount: str = "-"
    capsules: str = "-"
    valid: str = "-"
    cond: str = "-"
    effect: str = "-"
    seconds: float = 0.0
    note: str = ""
    stage_seconds: dict[str, float] = dataclasses.field(default_factory=dict)

    def cells(self) -> list[str]:
        return [self.robot, self.loads, self.mount, self.capsules, self.valid, self.cond, self.effect,
                f"{self.seconds:.0f}", self.note]


def short_reason(err: BaseException | str, limit: int = REASON_CHARS) -> str:
    """An error as one line of at most ``limit`` characters, folders left out of file paths."""
    text = str(err).strip() or type(err).__name__
    text = re.sub(r"\s+", " ", text)
    text = re.sub(r"(?:/[^\s'\":/]+)+/([^\s'\":/]+)", r"\1", text)
    return text if len(text) <= limit else text[: limit - 1] + "…"


def select_robots(names: str) -> list[BenchRobot]:
    """The robots of ``--robots a,b,c`` (empty: all of :data:`ROBOTS`; a model file's path runs
    with the defaults).

    Raises:
        ValueError: a name that is neither, listing the known names.
    """
    if not names.strip():
        return list(ROBOTS)
    known = {r.name: r for r in ROBOTS}
    chosen = []
    for name in (n.strip() for n in names.split(",") if n.strip()):
        if name in known:
            chosen.append(known[name])
        elif Path(name).suffix.lower() in (".urdf", ".sdf", ".xacro"):
            chosen.append(BenchRobot(Path(name).name.split(".")[0], str(Path(name).resolve())))
        else:
            raise ValueError(f"unknown robot '{name}' for --robots; known: {', '.join(known)}, or a model file path")
    return chosen


def model_argument(entry: BenchRobot) -> str:
    """What ``resolve_robot_config`` gets: a built-in name or a model file path."""
    if entry.model in builtin_robots() or Path(entry.model).is_absolute():
        return entry.model
    return str(example_robot_data_dir() / "robots" / entry.model)


def caps_yaml(entry: BenchRobot, options: BenchOptions) -> str:
    """The config file of the run: the entry's own YAML with the bench's caps merged in."""
    text = entry.config
    excitation = "  periods: 1\n" + (f"  harmonics: {options.harmonics}\n" if options.harmonics else "")
    if options.harmonics:
        excitation += "  cost_samples: 16\n  constraint_samples: 60\n"
    return (text + f"solver:\n  max_iterations: {options.max_iterations}\n  max_time: {options.max_time:g}\n"
            "  verbose: false\nparallel:\n  starts: 1\n  workers: 1\nexcitation:\n" + excitation)


def mount_of(robot: Robot) -> str:
    """How the robot stands: on its feet with balance, or its root welded upright, upside down
    or tilted, at the height of its base."""
    cfg = robot.config
    if cfg.support_points:
        return f"standing, {len(cfg.support_points)} feet, balance"
    w, x, y, z = (float(v) for v in cfg.base_quaternion_wxyz)
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    up = 1.0 - 2.0 * (x * x + y * y) / (norm * norm)  # z of the base's z axis in world
    pose = "upright" if up > 1 - 1e-6 else "ceiling" if up < -1 + 1e-6 else f"tilted {math.degrees(math.acos(up)):.0f}°"
    height = float(cfg.base_position[2])
    return f"{pose} ({robot.root_link})" + (f" z={height:g}" if height else "")


def capsules_of(plan) -> str:
    """Where the capsules came from (file, mesh, primitive) and how many; unchecked parts."""
    if plan.fitted is not None:
        kinds = sorted({k for v in plan.fitted.sources.values() for k in v.split("+")})
        count = len(load_capsule_file(plan.fitted.path).capsules)
        text = f"{'+'.join(kinds) or 'none'} {count}"
        unchecked = len(plan.fitted.unchecked)
    elif plan.config.robot.capsules:
        text = f"file {len(load_capsule_file(plan.config.robot.capsules).capsules)}"
        unchecked = len(plan.report.unchecked)
    else:
        text, unchecked = "none", len(plan.report.unchecked)
    return text + (f", {unchecked} unchecked" if unchecked else "")


def hidden_friction(robot: Robot, seed: int) -> str:
    """TRUTH.yaml text: Coulomb and viscous friction on every excited joint, sized to its effort
    limit (2 % and 1 %·s/rad; 0.3 N·m and 0.1 N·m·s/rad without one), 3 % inertial error,
    0.02 N·m torque noise and a 19-bit encoder. Integrated with radau3: Coulomb friction on
    light links makes the dynamics stiff."""
    coulomb, viscous = [], []
    for name, effort in zip(robot.joint_names, robot.limits.effort_max):
        effort = float(effort) if np.isfinite(effort) and effort > 0 else None
        coulomb.append(f"    {name}: {min(max(0.02 * effort, 0.05), 5.0) if effort else 0.3:.4g}")
        viscous.append(f"    {name}: {min(max(0.01 * effort, 0.02), 2.0) if effort else 0.1:.4g}")
    return (f"seed: {seed}\ninertia_perturbation: 0.03\nintegrator: radau3\neffects:\n"
            + ("  coulomb:\n" + "\n".join(coulomb) if coulomb else "  coulomb: {}") + "\n  viscous:\n" + "\n".join(viscous)
            + "\nnoise:\n  tau_std: 0.02\n  encoder_counts_per_rev: 524288\ncontrol:\n  rate_hz: 1000.0\n")


def effect_named(result, joints: int, revolute: int) -> str:
    """Whether the diagnosis named the hidden friction, on how many joints (Coulomb: of the
    ``revolute`` ones that have it)."""
    coulomb = {e.joint for e in result.effects if e.effect == "coulomb_friction"}
    viscous = {e.joint for e in result.effects if e.effect == "viscous_friction"}
    others = sorted({e.effect for e in result.effects} - {"coulomb_friction", "viscous_friction"})
    named = "yes" if coulomb or viscous else "no"
    text = f"{named}: coulomb {len(coulomb)}/{revolute}, viscous {len(viscous)}/{joints}"
    return text + (f" (+{', '.join(others)})" if others else "")


def _stage(row: Row, name: str, step: Callable[[], object]):
    """Runs one stage; a failure goes into the row's note (the caller stops there)."""
    start = time.perf_counter()
    try:
        return step()
    except Exception as err:  # noqa: BLE001 -- the bench reports every robot's failure and goes on
        row.note = f"{name}: {short_reason(err)}"
        return None
    finally:
        row.stage_seconds[name] = row.stage_seconds.get(name, 0.0) + time.perf_counter() - start


def run_robot(entry: BenchRobot, options: BenchOptions, folder: Path) -> Row:
    """The whole chain for one robot in ``folder``; never raises (failures are in the row)."""
    row, start = Row(entry.name), time.perf_counter()
    try:
        _run_stages(row, entry, options, folder)
    finally:
        row.seconds = time.perf_counter() - start
    return row


def _run_stages(row: Row, entry: BenchRobot, options: BenchOptions, folder: Path) -> None:
    caps = folder / "bench.yaml"
    caps.write_text(caps_yaml(entry, options))
    model = str(entry.build(folder)) if entry.build else model_argument(entry)
    config = _stage(row, "config", lambda: resolve_robot_config(model, caps))
    robot = _stage(row, "load", lambda: Robot(entry.name, config.robot)) if config is not None else None
    if robot is None:
        row.loads = row.note.split(": ", 1)[-1] or "no"
        row.note = row.note.split(": ", 1)[0] + " failed"
        return
    row.loads, row.mount = f"yes ({robot.n} joints)", mount_of(robot)
    plan = _stage(row, "optimize", lambda: optimize_motion(config, name=entry.name))
    if plan is None:
        return
    row.capsules = _stage(row, "capsules", lambda: capsules_of(plan)) or "?"
    row.cond = f"{plan.report.cond:.4g}" if math.isfinite(plan.report.cond) else "inf"
    if not plan.success or plan.motion is None:
        row.valid, row.note = "no", f"optimize: {short_reason(plan.report.message)}"
        return
    out = folder / "optimize"
    if _stage(row, "write", lambda: plan.write(out)) is None:
        return
    row.valid = _written_check(plan, out / "trajectory.json")
    if row.valid != "yes":
        return
    _identify_and_diagnose(row, plan, out / "trajectory.json", options, folder, entry)


def _written_check(plan, trajectory: Path) -> str:
    """The written trajectory.json replayed as trajectory.csv holds it, checked at 1 kHz."""
    try:
        motion, _ = load_motion(trajectory)
        check_written_motion(motion, plan.robot.limits, plan.robot.joint_names, 1000.0)
    except Exception as err:  # noqa: BLE001
        return f"no: {short_reason(err, 60)}"
    return "yes" + (" (not for hardware)" if plan.refusal else "")


def _identify_and_diagnose(row: Row, plan, trajectory: Path, options: BenchOptions, folder: Path,
                           entry: BenchRobot) -> None:
    robot = plan.robot
    truth = folder / "TRUTH.yaml"
    truth.write_text(hidden_friction(robot, options.seed))
    source = robot
    if entry.simulate_with is not None:
        twin = folder / "twin"
        twin.mkdir(exist_ok=True)
        source = Robot(entry.name, dataclasses.replace(plan.config.robot, model=str(entry.simulate_with(twin))))
    run = _stage(row, "simulate", lambda: simulate_run(source, trajectory, SimulateOptions(truth, duration=options.duration)))
    if run is None:
        return
    csv = folder / "run.csv"
    if _stage(row, "simulate", lambda: run.write(folder, name=csv.name)) is None:
        return
    data = _stage(row, "read", lambda: read_measurements(robot, csv, plan.config.data))
    if data is None:
        return
    model = _stage(row, "identify", lambda: identify_model(robot, data, IdentifyOptions.from_config(plan.config, method="wls")))
    if model is None:
        return
    result = _stage(row, "diagnose", lambda: diagnose(robot, data))
    if result is not None:
        row.effect = effect_named(result, robot.n, robot.n)


def format_row(cells: list[str], widths: list[int]) -> str:
    return "  ".join(c.ljust(w) for c, w in zip(cells, widths)).rstrip()


#: Column widths of the printed table (the note takes the rest of the line).
WIDTHS = [16, 34, 30, 20, 12, 9, 32, 5, 0]


def bench_robots(args) -> list[Row]:
    """Runs the bench on ``args.robots`` (all when empty) and prints the table."""
    options = BenchOptions(
        max_iterations=args.max_iterations if args.max_iterations is not None else BenchOptions.max_iterations,
        harmonics=getattr(args, "harmonics", None), duration=getattr(args, "duration", None), seed=args.seed,
    )
    try:
        entries = select_robots(getattr(args, "robots", "") or "")
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        raise SystemExit(2) from err
    print(format_row(list(COLUMNS), WIDTHS), flush=True)
    rows = []
    for entry in entries:
        with tempfile.TemporaryDirectory(prefix=f"pe_drake-bench-{entry.name}-") as tmp:
            row = run_robot(entry, options, Path(tmp))
        rows.append(row)
        print(format_row(row.cells(), WIDTHS), flush=True)
    stages = (", ".join(f"{k} {v:.0f}" for k, v in r.stage_seconds.items()) for r in rows)
    print("seconds per stage: " + "; ".join(f"{r.robot}: {s}" for r, s in zip(rows, stages)))
    valid = sum(r.valid.startswith("yes") for r in rows)
    named = sum(r.effect.startswith("yes") for r in rows)
    print(f"BENCH robots={len(rows)} loaded={sum(r.loads.startswith('yes') for r in rows)} valid={valid} "
          f"friction_named={named} total_s={sum(r.seconds for r in rows):.0f}")
    return rows
