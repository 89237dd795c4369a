"""Controller logs with their own column names: UR RTDE CSV, or any CSV through a column map.

A column map (config ``data.columns``) names the file's column for each of pe_drake's
quantities: ``{t: time, q.<joint>: ..., v.<joint>: ..., tau.<joint>: ...}`` or ``current.<joint>``
(motor current [A], converted with ``robot.drive_gains``). The delimiter is a comma, a semicolon,
a tab or spaces (UR's own RTDE writer). Fields with the robot's own model taken out are refused
by name (:data:`REFUSED`): no inertia can be identified from them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from pe_drake.exceptions import DataError
from pe_drake.limits import input_file_problem
from pe_drake.identification.csv_checks import SAVE_AS_UTF8, check_text_file, check_time_order, first_non_number
from pe_drake.identification.measurements import Measurement
from pe_drake.identification.readers.currents import torque_from_current

#: Column-name fragments refused as torques, with the reason.
REFUSED = {
    "actual_current_as_torque": "UR's actual_current_as_torque is gravity-compensated (the controller's model is "
    "taken out); use actual_current_0..5 with robot.drive_gains",
    "external_torque": "KUKA's external_torque is the torque left after the controller's own dynamic model; "
    "use the measured joint torque (measured_torque / effort)",
}
QUANTITIES = ("q", "v", "vdot", "tau", "current")


def _split(line: str, delimiter: str | None) -> list[str]:
    return [f.strip().strip('"') for f in (line.split(delimiter) if delimiter else line.split())]


def read_header(path: str | Path) -> tuple[list[str], str | None]:
    """(column names, delimiter; None: whitespace) of a delimited text file."""
    path = Path(path)
    problem = input_file_problem(path)
    if problem:
        raise DataError(f"measurement file {problem}", file=str(path))
    check_text_file(path)  # UTF-16 or another encoding: named, not a UnicodeDecodeError traceback
    with path.open(encoding="utf-8-sig") as f:
        header = next((line for line in f if line.strip()), "")
    delimiter = next((d for d in (",", ";", "\t") if d in header), None)
    return _split(header, delimiter), delimiter


def is_rtde(columns: Sequence[str]) -> bool:
    """A UR RTDE log: ``timestamp`` and ``actual_q_0`` columns."""
    return "timestamp" in columns and "actual_q_0" in columns


def rtde_columns(joints: Sequence[str], columns: Sequence[str], file: str) -> dict[str, str]:
    """The column map of a UR RTDE log (joints in UR's fixed order 0..5)."""
    if len(joints) != 6:
        raise DataError(f"an RTDE log has 6 joints (actual_q_0..5); the robot excites {len(joints)}: "
                        f"{', '.join(joints)}", file=file)
    has_current = "actual_current_0" in columns
    if not has_current:
        for name, reason in REFUSED.items():
            if any(c.startswith(name) for c in columns):
                raise DataError(f"the log has {name} but no actual_current_0..5: {reason}", file=file, column=name)
        raise DataError("the RTDE log has no actual_current_0..5 columns (motor currents) to identify from",
                        file=file)
    out = {"t": "timestamp"}
    for k, j in enumerate(joints):
        out[f"q.{j}"] = f"actual_q_{k}"
        out[f"current.{j}"] = f"actual_current_{k}"
        if f"actual_qd_{k}" in columns:
            out[f"v.{j}"] = f"actual_qd_{k}"
    return out


def _check_map(mapping: Mapping[str, str], joints: Sequence[str], columns: Sequence[str], file: str) -> None:
    for key, column in mapping.items():
        quantity, _, joint = key.partition(".")
        if key != "t" and (quantity not in QUANTITIES or joint not in joints):
            raise DataError(f"data.columns key '{key}' is not t or <quantity>.<joint> with a quantity of "
                            f"{', '.join(QUANTITIES)} and a joint of {', '.join(joints)}", file=file)
        if column not in columns:
            raise DataError(f"data.columns maps '{key}' to '{column}', which the file does not have; its columns: "
                            f"{', '.join(columns)}", file=file, column=column)
        for name, reason in REFUSED.items():
            if name in column and quantity in ("tau", "current"):
                raise DataError(f"column '{column}' cannot be used as {key}: {reason}", file=file, column=column)
    missing = [j for j in joints if f"q.{j}" not in mapping]
    if missing:
        raise DataError(f"data.columns gives no q.<joint> column for {', '.join(missing)}",
                        file=file)
    for j in joints:
        if (f"tau.{j}" in mapping) == (f"current.{j}" in mapping):
            raise DataError(f"data.columns must give exactly one of tau.{j} and current.{j}", file=file)


def read_mapped_csv(path: str | Path, joints: Sequence[str], mapping: Mapping[str, str],
                    drive_gains: Mapping[str, float] | None = None) -> Measurement:
    """Reads a delimited log through a column map (module docstring).

    Args:
        mapping: {``t`` | ``<quantity>.<joint>``: column}; ``t`` defaults to a column named
            t, time or timestamp.
        drive_gains: {joint: k [N·m/A]} for ``current.<joint>``.

    Raises:
        DataError: an unknown key or column, a refused field, no time column, a non-numeric
            value, non-increasing time, currents without gains.
    """
    file = str(path)
    columns, delimiter = read_header(path)
    mapping = dict(mapping)
    if "t" not in mapping:
        mapping["t"] = next((c for c in ("t", "time", "timestamp") if c in columns), "")
        if not mapping["t"]:
            raise DataError(f"no time column: name it in data.columns as t: <column>; columns: {', '.join(columns)}",
                            file=file)
    _check_map(mapping, joints, columns, file)
    _check_unique_columns(columns, set(mapping.values()), file)
    keys = list(mapping)
    try:
        table = np.loadtxt(path, delimiter=delimiter, skiprows=1, usecols=[columns.index(mapping[k]) for k in keys],
                           ndmin=2, comments=None, encoding="utf-8-sig")
    except UnicodeDecodeError:  # past the first 64 kB that check_text_file reads
        _locate_non_utf8(path, file)
        raise
    except ValueError as err:
        _locate_non_number(path, delimiter, columns, [mapping[k] for k in keys], file)
        raise DataError(f"cannot read the values as numbers: {err}", file=file) from err
    if not np.isfinite(table).all():
        r, c = np.argwhere(~np.isfinite(table))[0]
        raise DataError("value is not a finite number", file=file, column=mapping[keys[c]], row=int(r) + 1)
    col = {k: table[:, i] for i, k in enumerate(keys)}
    t = col["t"]
    check_time_order(t, file, column=mapping["t"])

    def block(quantity: str) -> np.ndarray | None:
        if not all(f"{quantity}.{j}" in col for j in joints):
            return None
        return np.column_stack([col[f"{quantity}.{j}"] for j in joints])

    tau = np.column_stack([col[f"tau.{j}"] if f"tau.{j}" in col else np.zeros_like(t) for j in joints])
    notes = []
    current_joints = [j for j in joints if f"current.{j}" in col]
    if current_joints:
        current = np.column_stack([col[f"current.{j}"] for j in current_joints])
        k_tau = torque_from_current(current, current_joints, drive_gains or {}, file)
        for i, j in enumerate(current_joints):
            tau[:, list(joints).index(j)] = k_tau[:, i]
        notes.append(f"motor currents of {', '.join(current_joints)} multiplied by robot.drive_gains (τ = k·i)")
    return Measurement(t - t[0], block("q"), tau, block("v"), block("vdot"), tuple(joints), file, notes=tuple(notes))


def _check_unique_columns(columns: Sequence[str], used: set[str], file: str) -> None:
    """Refuses a header naming a used column twice."""
    twice = [c for c in dict.fromkeys(columns) if c in used and columns.count(c) > 1]
    if twice:
        positions = ", ".join(f"'{c}' (columns {', '.join(str(i + 1) for i, n in enumerate(columns) if n == c)})"
                              for c in twice)
        raise DataError(f"the header names {positions} more than once: which copy holds the data is unknown; "
                        "remove or rename the repeated column", file=file, column=twice[0])


def _locate_non_utf8(path, file: str) -> None:
    """Raises naming the line and the byte of the first text that is not UTF-8."""
    with Path(path).open("rb") as f:
        for number, line in enumerate(f, 1):
            try:
                line.decode("utf-8")
            except UnicodeDecodeError as err:
                raise DataError(f"line {number}: byte {line[err.start]:#04x} is not UTF-8 text (Latin-1 or another "
                                f"encoding?): {SAVE_AS_UTF8}", file=file) from None


def _locate_non_number(path, delimiter: str | None, columns: list[str], used: list[str], file: str) -> None:
    """Raises naming the row, line and column of the first field numpy could not read."""
    with Path(path).open(encoding="utf-8-sig") as f:
        lines = [(n + 1, line) for n, line in enumerate(f) if line.strip()][1:]
    found = first_non_number(((n, _split(line, delimiter)) for n, line in lines),
                             {columns.index(c): c for c in used})
    if found is not None:
        row, line, column, raw = found
        raise DataError(f"'{raw}' is not a number (line {line} of the file)", file=file, column=column, row=row)


def identity_columns(columns: Sequence[str], joints: Sequence[str]) -> dict[str, str]:
    """The column map of a pe_drake CSV (``current.<joint>`` instead of ``tau.<joint>``)."""
    return {c: c for c in columns if c == "t" or (c.partition(".")[0] in QUANTITIES and c.partition(".")[2] in joints)}
