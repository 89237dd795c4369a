"""The front door of ``pe-drake identify --payload``: :func:`identify_payload_runs` reads the
runs, identifies the payload with the arm frozen and returns a :class:`PayloadIdentification`
that prints the vendor formats and writes payload.json and model_with_payload.urdf."""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from pe_drake.exceptions import ConfigError
from pe_drake.excitation.payload_motion import undetermined_note
from pe_drake.excitation.trajectory_file import load_trajectory
from pe_drake.identification.identified_file import load_identified
from pe_drake.identification.intake import prepare_measurement, read_measurements
from pe_drake.identification.payload import (PayloadBox, PayloadOptions, PayloadResult,
                                             arm_parameters, check_payload_trajectory,
                                             identify_payload)
from pe_drake.identification.payload_formats import vendor_formats, write_payload_urdf
from pe_drake.io_utils import finite_json, staged_output_dir
from pe_drake.multibody.robot import Robot
from pe_drake.output_paths import check_output_dir

#: The controller whose payload command a flange link's name stands for (the others go to payload.json).
VENDOR_OF_FLANGE = {"panda_link8": "franka", "tool0": "ur", "iiwa_link_ee": "kuka"}


def parse_payload_box(text: str | None) -> PayloadBox | None:
    """``cx,cy,cz,sx,sy,sz`` [m] in the payload link's frame (None: no box); ConfigError if not six
    numbers."""
    if not text:
        return None
    try:
        values = [float(x) for x in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 6:
        raise ConfigError(f"--payload-box takes cx,cy,cz,sx,sy,sz [m] in the payload link's frame, got {text!r}")
    return PayloadBox(tuple(values[:3]), tuple(values[3:]))


@dataclasses.dataclass(frozen=True, eq=False)
class PayloadIdentification:
    """An identified payload, the runs it came from and its vendor formats."""

    robot: Robot
    result: PayloadResult
    loaded: int
    unloaded: int
    formats: dict[str, Any]
    arm: Any
    wall_time: float
    flange_given: bool = False

    def summary_lines(self) -> list[str]:
        r, p, f = self.result, self.result.payload, self.formats
        lines = [f"payload on {r.link} ({self.loaded} loaded, {self.unloaded} unloaded run(s), {r.samples} samples, "
                 f"{r.wall_time:.2f} s): mass {p.mass:.4f} ± {r.mass_std:.2g} kg, CoM "
                 f"{[round(float(x), 5) for x in p.com]} ± {[float(f'{x:.2g}') for x in r.com_std]} m"]
        if r.undetermined:
            lines.append(undetermined_note(r.undetermined) + " (σ nan, null in payload.json)")
        if not self.unloaded:
            lines.append("note: no unloaded run: the arm's model errors go into the payload, and the ± above are the "
                         "noise's alone, without them (give --unloaded, a run of the same motion without the payload)")
        if Path(self.robot.model_path).suffix.lower() != ".urdf":
            lines.append(f"note: model_with_payload.urdf not written: '{Path(self.robot.model_path).name}' is not a URDF "
                         "(payload.json holds the payload)")
        vendor = VENDOR_OF_FLANGE.get(f["flange"])
        if vendor == "franka":
            lines.append(f"in {f['flange']}: Franka setLoad mass {f['franka']['load_mass']:.4f}, "
                         f"F_x_Cload {[round(float(x), 5) for x in f['franka']['F_x_Cload']]}")
        elif vendor == "ur":
            lines.append(f"in {f['flange']}: UR " + f["ur"]["set_target_payload"])
        elif vendor == "kuka":
            lines.append(f"in {f['flange']}: KUKA " + f["kuka"]["krl"])
        else:  # not a known vendor's flange: no vendor's command is the robot's own (issue 37)
            lines.append(f"in {f['flange']}: mass {p.mass:.4f} kg; the Franka, UR and KUKA formats are in payload.json "
                         "'vendor'" + ("" if self.flange_given or f["flange"] != r.link else
                                       " (frame: the payload link; --flange names the controller's flange)"))
        return lines

    def write(self, folder: str | Path) -> list[str]:
        """payload.json (with the vendor formats) and model_with_payload.urdf, both or neither (the
        URDF only for a robot loaded from one: payload.json says so, as identify does for model.urdf)."""
        out = check_output_dir(folder)
        urdf = Path(self.robot.model_path).suffix.lower() == ".urdf"
        with staged_output_dir(out, "payload.json", ("payload.json", "model_with_payload.urdf")) as tmp:
            d = self.result.to_dict()
            d["vendor"] = self.formats
            if not urdf:  # an SDF robot: the fit is still written (issue 37)
                d["model_with_payload_urdf"] = f"not written: '{Path(self.robot.model_path).name}' is not a URDF"
            (tmp / "payload.json").write_text(json.dumps(finite_json(d), indent=2))
            if urdf:
                write_payload_urdf(tmp / "model_with_payload.urdf", self.robot, self.result.payload, self.result.link,
                                   arm_parameters(self.robot, self.arm))
        return ["payload.json", "model_with_payload.urdf"] if urdf else ["payload.json"]


def identify_payload_runs(robot: Robot, loaded: Sequence[str | Path], unloaded: Sequence[str | Path], link: str, *,
                          model: str | Path | None = None, trajectory: str | Path | None = None,
                          cutoff_hz: float | None = None, filtering: bool = True, box: PayloadBox | None = None,
                          flange: str | None = None) -> PayloadIdentification:
    """What ``pe-drake identify --payload`` does: each run read, checked and preprocessed, and the
    payload identified with the arm frozen at ``model`` (an identified.json; default the URDF's).

    Raises:
        DataError, ConfigError: unreadable runs, a trajectory for another payload link, a bad box.
    """
    start = time.perf_counter()
    if trajectory:
        _, data = load_trajectory(trajectory)
        check_payload_trajectory(data, link, trajectory)

    def runs(paths):
        return [prepare_measurement(robot, read_measurements(robot, p), cutoff_hz=cutoff_hz, filtering=filtering)
                for p in paths]

    loaded_runs, unloaded_runs = runs(loaded), runs(unloaded)
    arm = load_identified(model, robot) if model else None
    result = identify_payload(robot, loaded_runs, unloaded_runs, link, arm, PayloadOptions(box=box))
    formats = vendor_formats(robot, result.payload, result.link, flange or None)
    return PayloadIdentification(robot, result, len(loaded_runs), len(unloaded_runs), formats, arm,
                                 time.perf_counter() - start, bool(flange))
