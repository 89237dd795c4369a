"""The front door of ``pe-drake simulate``: :func:`simulate_run` tracks a trajectory file's
motion on a perturbed "true" robot (the URDF's, or an identified model's with ``--model``) and
returns a :class:`SimulatedRun` that writes its CSV and the ``.truth.json`` beside it."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from pe_drake.exceptions import ConfigError, check_joints
from pe_drake.excitation.ramp import check_within_limits
from pe_drake.excitation.trajectory_file import load_motion
from pe_drake.identification.measurements import Measurement, measurement_to_csv_text
from pe_drake.io_utils import atomic_write_text
from pe_drake.multibody.robot import Robot
from pe_drake.multibody.robot_model import FILE_KEYS, RobotModel
from pe_drake.output_paths import output_file
from pe_drake.simulation.contact import capsule_contacts
from pe_drake.simulation.simulated_model import load_simulation_model
from pe_drake.simulation.simulation import simulate, truth_path_for
from pe_drake.simulation.truth import make_truth, read_truth_file

_RECORDED = {"joint_torque": "tau", "base_wrench": "wrench", "both": "tau and wrench"}
#: A joint tracking worse than this [rad RMS] gets a warning: the recorded motion is no longer
#: the one planned (and checked against the limits).
LARGE_TRACKING_ERROR = 0.02
#: What a capsule overlap along a simulated run means (:mod:`pe_drake.simulation.contact`).
CONTACT_NOTE = ("the simulated robot moves through (no contact force); a real robot whose links fill their capsules "
                "would collide there: check the trajectory (optimize with excitation.collision_margin)")


@dataclasses.dataclass(frozen=True, eq=False)
class SimulatedRun:
    """A simulated measurement and what produced it (the ``.truth.json`` content)."""

    robot: str
    measurement: str
    data: Measurement
    truth: dict[str, Any]
    prismatic: tuple[str, ...] = ()  # joints whose error is in mm, not mrad

    def summary_lines(self) -> list[str]:
        sim = self.truth["simulation"]
        model = self.truth.get("simulated_model")
        head = [f"the robot is the model of '{model['file']}' (parameters and drive terms)"] if model else []
        head += [f"note: {note}" for note in (model or {}).get("notes", ())]
        lines = head + [f"simulated {sim['duration']:.3g} s of '{self.robot}' at {sim['rate_hz']:g} Hz: "
                        f"{sim['samples']} samples in {sim['wall_time_s']:.2f} s wall time",
                        "tracking error RMS: " + ", ".join(f"{j} {1e3 * e:.3g} {self._unit(j)}"
                                                          for j, e in sim["tracking_error_rms"].items())]
        lines += self._model_file_friction()
        contacts = {k: c for k, c in sim.get("capsule_contacts", {}).items() if k != "note"}
        lines += [f"warning: the capsules of {pair} overlap by up to {1e3 * c['max_overlap_m']:.3g} mm in "
                  f"{c['from_s']:.3g}-{c['to_s']:.3g} s: {CONTACT_NOTE}" for pair, c in contacts.items()]
        joint, worst = max(sim["tracking_error_rms"].items(), key=lambda item: item[1])
        if worst > LARGE_TRACKING_ERROR:
            lines.append(f"warning: {joint} tracks its trajectory to {1e3 * worst:.3g} {self._unit(joint)} RMS: the run "
                         f"is not the planned motion (it may leave the joint limits). {self._tracking_cause(joint)}")
        return lines

    def _tracking_cause(self, joint: str) -> str:
        """The likeliest reason a joint does not track: what the controller's model lacks."""
        effects = self.truth.get("effects", {})
        payload = effects.get("payload", {})
        prior_control = self.truth.get("control", {}).get("model") == "prior"
        armature = effects.get("armature", {}).get("values", {}).get(joint, 0.0)
        if payload.get("link"):
            return (f"The truth's payload ({payload['mass']:g} kg on {payload['link']}) is not in the controller's "
                    "model: raise control.kp and control.kd in the truth file, or give the controller the payload")
        if prior_control and armature > 0:
            return (f"The truth's armature ({armature:g} kg·m² on {joint}) is not in the controller's model "
                    "(control.model: prior, gains kp·M, kd·M): raise control.kp and control.kd in the truth file, or set "
                    'control.model: "true"')
        return ("The truth's friction is large for the controller (gains kp·M, kd·M scale with the link's "
                "inertia): raise control.kp and control.kd in the truth file or lower the friction")

    def _model_file_friction(self) -> list[str]:
        """Notes on the joints the truth leaves to the model file's friction."""
        lines = []
        for key, unit in (("viscous", "N·m·s/rad"), ("coulomb", "N·m")):
            table = self.truth.get("effects", {}).get(key, {})
            kept = {j: v for j, v in table.get("values", {}).items()
                    if table.get("source", {}).get(j) == "model file" and v > 0}
            if kept:
                lines.append(f"note: {key} friction of the model file kept where the truth does not set it: "
                             + ", ".join(f"{j} {v:.3g}" for j, v in kept.items()) + f" {unit}")
        return lines

    def _unit(self, joint: str) -> str:
        return "mm" if joint in self.prismatic else "mrad"

    @property
    def recorded(self) -> str:
        """What the CSV records: "tau", "wrench" or "tau and wrench"."""
        return _RECORDED[self.measurement]

    def write(self, folder: str | Path, *, name: str = "run.csv") -> list[str]:
        """Writes the CSV ``folder/name`` and its ``.truth.json`` beside it, both or neither;
        returns their paths."""
        out = output_file(folder, name)
        out.parent.mkdir(parents=True, exist_ok=True)
        csv_text = measurement_to_csv_text(self.data.replace(source=str(out)))
        truth_file = truth_path_for(out)
        atomic_write_text(truth_file, json.dumps({**self.truth, "data_file": out.name}, indent=2) + "\n")
        try:
            atomic_write_text(out, csv_text)
        except BaseException:
            truth_file.unlink(missing_ok=True)  # nothing half-written
            raise
        return [str(out), str(truth_file)]


@dataclasses.dataclass(frozen=True)
class SimulateOptions:
    """What ``simulate`` runs the motion on."""

    truth: str | Path | None = None  # TRUTH.yaml: the robot's perturbation, noise and control
    # identified.json or augmented_model.json: the simulated robot has its parameters and drive
    # terms, ``truth``'s effects, noise and control on top (without: no noise, default control)
    model: str | Path | None = None
    duration: float | None = None  # simulated time [s] (None: the motion's)
    measurement: str = "joint_torque"  # or "base_wrench" or "both"

    def __post_init__(self):
        if self.truth is None and self.model is None:
            raise ConfigError("give a TRUTH.yaml (--truth), an identified model (--model), or both")
        if self.duration is not None and not 0 < self.duration <= 3600:
            raise ConfigError(f"--duration must be in (0, 3600] s, got {self.duration!r}")
        if self.measurement not in _RECORDED:
            raise ConfigError(f"measurement '{self.measurement}' is not one of {', '.join(_RECORDED)}")


def simulate_run(robot: Robot, trajectory: str | Path, options: SimulateOptions, *,
                 progress: Callable[[str], None] | None = None) -> SimulatedRun:
    """What ``pe-drake simulate`` does: the motion of ``trajectory``'s trajectory.csv (ramps and
    periods; after its end the robot rests) on the robot of ``options``; ``progress`` gets a
    line before the simulation starts (it can take tens of seconds).

    Raises:
        DataError: a trajectory file for other joints, or outside the robot's limits; a model
            file that is not an identified model of this robot.
        ConfigError: a duration outside (0, 3600] s, a bad truth file, no truth and no model.
        TypeError: ``options`` that is not a :class:`SimulateOptions`.
    """
    if not isinstance(options, SimulateOptions):
        raise TypeError(f"simulate_run takes SimulateOptions(truth, model=...) as options, got {options!r}")
    truth, model, measurement = options.truth, options.model, options.measurement
    if not np.any(robot.phi_model[0::10] > 0):  # a singular mass matrix; the controller's gains scale with it
        raise ConfigError(f"robot '{robot.name}' has no inertial parameters (every moving body's mass is 0; no "
                          "<inertial> in its model) to simulate: simulate --robot the model.urdf of "
                          "identify --method physical (with --truth its drive_effects.yaml)")
    motion, data = load_motion(trajectory)  # validated before any work
    spec, where = (read_truth_file(truth), f"truth file '{truth}'") if truth is not None else ({}, "")
    check_joints(robot, data["joints"], file=str(trajectory), what="the trajectory")
    check_within_limits(motion, robot.limits, robot.joint_names, source=str(trajectory))
    duration = options.duration if options.duration is not None else motion.duration
    if not 0 < duration <= 3600:  # the motion's own
        raise ConfigError(f"the motion of '{trajectory}' lasts {duration:g} s: simulate at most 3600 s (--duration)")
    # the truth's values and names checked before any work (a model's terms are added after)
    truth_spec = make_truth(robot, where=where, **spec)
    extra = None
    if model is not None:
        sim_model = load_simulation_model(model, robot)
        extra = {"simulated_model": _model_record(sim_model, str(model))}
        truth_spec = make_truth(robot, model=sim_model, where=where, **spec)
    if progress is not None:
        progress(f"simulating {robot.name}: {duration:.3g} s of {Path(trajectory).name} "
                 f"(integrator {truth_spec.integrator}) ...")
    measured, truth_dict = simulate(robot, motion, truth_spec, duration, measurement=measurement)
    contacts = capsule_contacts(robot, measured.t, measured.q)
    truth_dict["simulation"]["capsule_contacts"] = {
        c.pair: c.to_dict() for c in contacts} | ({"note": CONTACT_NOTE} if contacts else {})
    return SimulatedRun(robot.name, measurement, measured, {**truth_dict, **(extra or {})},
                        tuple(j.name for j in robot.joints if j.kind == "prismatic"))


def _model_record(model: RobotModel, source: str) -> dict[str, Any]:
    """The simulated model's record in the run's ``.truth.json``."""
    def per_joint(x):
        return dict(zip(model.joints, map(float, x)))

    return {"file": source, "notes": list(model.notes),
            "drive_terms": {field: per_joint(model.term(t)) for t, field in FILE_KEYS.items()},
            "torque_delay": model.torque_delay, "presliding_friction": per_joint(model.presliding),
            "presliding_stiffness": per_joint(model.presliding_stiffness)}
