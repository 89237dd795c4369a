"""The front door of ``pe-drake export``: :func:`export_model` writes the identified robot in the
format where it is used, and checks it there (MuJoCo's ``mj_inverse`` for an MJCF, Drake's
inverse dynamics for a URDF or SDFormat, against the model on random states).
"""

from __future__ import annotations

import dataclasses
import shutil
import tempfile
from pathlib import Path

import numpy as np

from pe_drake.exceptions import ConfigError
from pe_drake.export.controller import feedforward_yaml, friction_torque, gains_yaml
from pe_drake.export.drake_files import drake_check, sdf_text, urdf_export_text
from pe_drake.export.mjcf import mjcf_files, spring_held_offsets, unheld_terms
from pe_drake.export.model_source import exported_model, identified_spread, projection_change, random_states
from pe_drake.export.mujoco_dynamics import load_mjcf, mujoco_torques
from pe_drake.identification.drive_terms import filtered_coulomb
from pe_drake.identification.intake import prepare_measurement
from pe_drake.identification.measurements import Measurement
from pe_drake.identification.time_window import TimeWindow
from pe_drake.io_utils import atomic_write_text, chmod_as_created
from pe_drake.multibody.robot import Robot
from pe_drake.multibody.robot_model import RobotModel
from pe_drake.output_paths import output_file

#: Formats and the suffix of their file.
FORMATS = {"mjcf": ".xml", "urdf": ".urdf", "sdf": ".sdf", "feedforward": ".yaml", "gains": ".yaml"}
#: Largest relative torque difference an exported file may show against the model.
CHECK_TOLERANCE = 1e-6


@dataclasses.dataclass(frozen=True)
class ExportOptions:
    """What ``export`` writes (``bandwidth_hz`` to ``samples``: gains only)."""

    to: str = "mjcf"  # one of FORMATS
    bandwidth_hz: float = 10.0  # [Hz]
    damping_ratio: float = 1.0
    sigma_k: float = 2.0  # randomization ranges value ± k·σ
    samples: int = 10  # physically consistent models drawn from σ
    seed: int = 0
    window: TimeWindow | None = None  # the part of the held-out run used (cut after filtering)
    meshdir: str = ""  # mjcf: the folder beside the file for its visual meshes ("": no geometry)

    def __post_init__(self):
        if self.meshdir and (Path(self.meshdir).name != self.meshdir or self.meshdir in (".", "..")):
            raise ConfigError(f"export meshdir '{self.meshdir}' must be a folder name (it is written beside the file)")
        if self.to not in FORMATS:
            raise ConfigError(f"export format '{self.to}' is not one of {', '.join(FORMATS)}")
        for name in ("bandwidth_hz", "damping_ratio", "sigma_k"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ConfigError(f"export {name} = {value!r}: give a positive number")
        if not 0 <= self.samples <= 10000:
            raise ConfigError(f"export samples = {self.samples}: give 0 to 10000")


@dataclasses.dataclass(frozen=True, eq=False)
class ExportResult:
    """An exported file's text and what it took."""

    format: str
    text: str
    model: RobotModel  # the model exported (physically consistent)
    source: str = ""  # the model file ("": the robot's own, the CAD model)
    unheld: tuple[str, ...] = ()  # what the format cannot hold of the model, one sentence each
    figures: dict = dataclasses.field(default_factory=dict)  # {name: value} of the checks
    meshdir: str = ""  # the mesh folder's name beside the file ("": none)
    meshes: dict = dataclasses.field(default_factory=dict)  # {file name: content} of that folder

    def summary_lines(self) -> list[str]:
        """What the file holds and leaves out, and the checks' figures."""
        lines = [f"exported {self.source or 'the CAD model'} as {self.format}"]
        lines += [f"note: {n}" for n in self.model.notes]
        lines += [f"not held by {self.format}: {n}" for n in self.unheld]
        for name, value in self.figures.items():
            if isinstance(value, dict):  # per joint
                value = ", ".join(f"{j} {x:.3g}" for j, x in value.items())
            lines.append(f"{name}: {value:.3g}" if isinstance(value, float) else f"{name}: {value}")
        return lines

    def write(self, folder: str | Path, *, name: str = "") -> list[str]:
        """Writes ``folder/name`` (default ``model`` + suffix) and its mesh folder, whole or not;
        returns the paths written."""
        path = output_file(folder, name or f"model{FORMATS[self.format]}")
        path.parent.mkdir(parents=True, exist_ok=True)
        if not self.meshes:
            atomic_write_text(path, self.text)
            return [str(path)]
        meshes = write_folder(path.parent / self.meshdir, self.meshes)
        try:
            atomic_write_text(path, self.text)
        except BaseException:
            shutil.rmtree(meshes, ignore_errors=True)
            raise
        return [str(path), str(meshes)]


def write_folder(folder: Path, files: dict[str, bytes]) -> Path:
    """Writes ``files`` into ``folder`` whole: a temporary folder beside it, renamed into place."""
    folder.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", dir=folder.parent))
    try:
        for name, content in files.items():
            (staging / name).write_bytes(content)
        chmod_as_created(staging)  # mkdtemp's 0700 would hide the meshes from other users (a simulator's)
        old = None
        if folder.exists():
            old = folder.with_name(f"{staging.name}.old")
            folder.rename(old)
        staging.rename(folder)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return folder


def export_model(robot: Robot, model: str | Path | None, options: ExportOptions | None = None, *,
                 held_out: Measurement | None = None, progress=None) -> ExportResult:
    """What ``pe-drake export`` does (module docstring).

    Args:
        model: identified.json (any method) or augmented_model.json; None: the robot's own model.
        held_out: a raw measured run to report the projection's and the feed-forward's effect on.
        progress: called with a line before each slow step (mesh conversion, the checks).

    Raises:
        ConfigError: a format the robot cannot be written in, a file that fails its check.
        DataError: a model file of another robot.
    """
    options = options or ExportOptions()
    say = progress or (lambda line: None)
    say(f"reading {model or 'the CAD model'}")
    exported, source = exported_model(robot, model), str(model or "")
    figures: dict = {}
    data = prepare_measurement(robot, held_out, window=options.window) if held_out is not None else None
    if model is not None:
        # without a held-out run, random states inside the limits show the projection's size
        states = data if data is not None else _random_run(robot, options.seed)
        change = projection_change(robot, model, exported, states)
        if change is not None:
            where = "held-out" if data is not None else f"{states.num_samples} random states'"
            figures[f"projection: {where} RMS change per joint [N·m]"] = dict(zip(robot.joint_names, map(float, change)))
    unheld = tuple(unheld_terms(robot, exported, options.to))
    meshes: dict = {}
    if options.to == "mjcf":
        say("writing the MJCF" + (" and its meshes" if options.meshdir else ""))
        mjcf = mjcf_files(robot, exported, meshdir=options.meshdir or None, source=source)
        text, unheld, meshes = mjcf.text, tuple(mjcf.unheld), mjcf.meshes
        say("checking it in MuJoCo")
        figures.update(_mujoco_check(robot, exported, text, meshes))
        if mjcf.notes:
            figures["visuals left out"] = "; ".join(mjcf.notes)
    elif options.to in ("urdf", "sdf"):
        text = (urdf_export_text if options.to == "urdf" else sdf_text)(robot, exported, source)
        say("checking it in Drake")
        figures[f"Drake inverse dynamics of the {options.to} vs the model (relative)"] = drake_check(
            robot, exported, text, FORMATS[options.to], tolerance=CHECK_TOLERANCE)
    elif options.to == "feedforward":
        check = _feedforward_check(robot, exported, data, held_out) if data is not None else None
        text = feedforward_yaml(robot, exported, check, source)
        figures.update(check or {})
        unheld = ()
    else:
        q = data.q if data is not None else random_states(robot, 200, options.seed)[0]
        spread = identified_spread(robot, model)
        text = gains_yaml(robot, exported, spread, q, bandwidth_hz=options.bandwidth_hz,
                          damping_ratio=options.damping_ratio, sigma_k=options.sigma_k, samples=options.samples,
                          seed=options.seed, source=source)
        if spread is not None and spread.note:
            figures["randomization"] = spread.note
        unheld = ()
    return ExportResult(options.to, text, exported, source, unheld, figures, options.meshdir if meshes else "", meshes)


def _random_run(robot: Robot, seed: int, samples: int = 200) -> Measurement:
    """Random states (:func:`~pe_drake.export.model_source.random_states`) as a run without torques."""
    q, v, vd = random_states(robot, samples, seed)
    return Measurement(np.arange(samples, dtype=float), q, np.zeros_like(q), v, vd, tuple(robot.joint_names))


def _mujoco_check(robot: Robot, model: RobotModel, text: str, meshes: dict) -> dict:
    """MuJoCo loads the MJCF and its mj_inverse reproduces the model (figures), or raises."""
    try:
        mj = load_mjcf(text, text=True, assets=meshes)
    except ImportError:
        return {"MuJoCo check": "skipped: mujoco is not installed (pip install 'pe_drake[mujoco]')"}
    q, v, vd = random_states(robot, 20)
    want = model.torque(robot, q, v, vd, coulomb=False, offset=False, spring=True) + spring_held_offsets(model, "mjcf")
    got = mujoco_torques(mj, robot.joint_names, q, v, vd)
    error = float(np.max(np.abs(got - want)) / max(float(np.max(np.abs(want))), 1e-12))
    if not error <= CHECK_TOLERANCE:
        raise ConfigError(f"the MJCF does not reproduce the model in MuJoCo: torques differ by {error:.3g} relative")
    return {"MuJoCo mj_inverse vs the model (relative)": error}


def _feedforward_check(robot: Robot, model: RobotModel, data, raw) -> dict:
    """RMS error [N·m] per joint of the gravity + friction feed-forward and of the whole model."""
    zero = np.zeros_like(data.v)
    coulomb = filtered_coulomb(raw, data, model.velocity_scale)
    friction = friction_torque(model, data.v, coulomb)
    gravity_ff = model.torque(robot, data.q, zero, zero, coulomb=False, offset=False) + friction
    whole = model.torque(robot, data.q, data.v, data.vd, coulomb=False, offset=False) + friction \
        - model.viscous * data.v

    def rms(x):
        return dict(zip(robot.joint_names, (float(r) for r in np.sqrt(np.mean(x**2, axis=0)))))

    return {"gravity + friction feed-forward RMS error [N·m]": rms(data.tau - gravity_ff),
            "whole model RMS error [N·m]": rms(data.tau - whole), "measured RMS [N·m]": rms(data.tau)}
