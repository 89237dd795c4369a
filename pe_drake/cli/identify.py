"""``pe-drake identify`` and ``pe-drake validate``: from measured data to a model and back."""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np

from pe_drake.cli.common import config_from_args, measurement_from_args, print_notes, read_log_from_args, robot_from_args
from pe_drake.exceptions import ConfigError
from pe_drake.excitation.trajectory_file import load_trajectory
from pe_drake.identification.channels import measured_values
from pe_drake.identification.data_checks import check_against_model
from pe_drake.identification.drive_terms import (
    DriveTermOptions,
    drive_effects_yaml,
    drive_summary,
    filtered_coulomb,
    format_percent,
    urdf_dynamics,
)
from pe_drake.identification.estimators import (
    fit_warnings,
    identify,
    predict,
    predict_wrench,
    prepare_measurement,
    torque_errors,
)
from pe_drake.identification.identified_file import (
    load_identified,
    result_to_dict,
    standard_from_base,
    standard_parameters_dict,
)
from pe_drake.identification.physical_fit import bounds_from_config
from pe_drake.io_utils import atomic_write_text, staged_output_dir
from pe_drake.multibody.inertia import PhysicallyInvalidError, validity_problems
from pe_drake.multibody.sensors import MeasurementType
from pe_drake.multibody.urdf import write_robot_urdf
from pe_drake.output_paths import IDENTIFY_OUTPUTS, check_output_dir, check_output_file, remove_stale_outputs
from pe_drake.plots import save_figure


def _trajectory_band(path: str | None) -> tuple[float | None, int | None]:
    """(fundamental [Hz], harmonics) of a trajectory.json, to choose the filter cut-off: the
    highest harmonic the motion uses, not the file's zero-padded count (which set 400 Hz)."""
    if not path:
        return None, None
    trajectory, _ = load_trajectory(path)
    return trajectory.omega / (2 * math.pi), max(trajectory.highest_harmonic, 1)


def _check_cutoff(cutoff: float | None) -> None:
    if cutoff is not None and not (math.isfinite(cutoff) and cutoff > 0):
        raise ConfigError(f"--cutoff must be a positive frequency [Hz], got {cutoff}")


def identify_command(args: argparse.Namespace) -> int:
    """Runs ``pe-drake identify``: identified.json, model.urdf (when physically valid),
    residual plot; nothing is written on error."""
    check_output_dir(args.out)  # before any work
    _check_cutoff(args.cutoff)
    start = time.perf_counter()
    config = config_from_args(args)
    measurement = measurement_from_args(args, config)
    robot = robot_from_args(args, config)
    raw = read_log_from_args(args, robot, config)
    f0, harmonics = _trajectory_band(getattr(args, "trajectory", None))
    data = prepare_measurement(
        robot,
        raw,
        cutoff_hz=args.cutoff,
        fundamental_hz=f0,
        harmonics=harmonics,
        filtering=not getattr(args, "no_filter", False),
        max_gap_s=config.data.max_gap_s,
    )
    check_against_model(robot, data)  # sign-flipped torque columns
    _print_data_summary(args, robot, raw, data)
    print_notes(data)
    choice = config.identification
    drive = DriveTermOptions(getattr(args, "drive_terms", None) or choice.drive_terms, choice.coulomb_velocity_scale)
    coulomb = filtered_coulomb(raw, data, drive.velocity_scale) if data is not raw else None
    result = identify(robot, data, args.method, measurement=measurement, drive_terms=drive,
                      bounds=bounds_from_config(choice), coulomb=coulomb)
    _print_fit_summary(args.method, robot, result)
    for line in drive_summary(result.drive) + fit_warnings(result):
        print(line)
    phi, note = _model_parameters(robot, result)
    out = Path(args.out)
    with staged_output_dir(out) as tmp:
        model_file = None
        if phi is not None:
            try:
                damping, rotor, urdf_notes = urdf_dynamics(result.drive)
                write_robot_urdf(tmp / "model.urdf", robot, phi, damping=damping, rotor_inertia=rotor)
                model_file = "model.urdf"
                note = "; ".join([note] * bool(note) + urdf_notes)
            except (PhysicallyInvalidError, ConfigError) as err:
                note = f"model.urdf not written: {err}"
        d = result_to_dict(result, robot, model_file)
        if result.phi is None and phi is not None:
            d["standard_parameters"] = standard_parameters_dict(robot, phi)
            d["physically_valid"] = True
        if note:
            d["note"] = note
        d["total_time_s"] = time.perf_counter() - start
        (tmp / "identified.json").write_text(json.dumps(d, indent=2))
        _plot_residuals(tmp / "residuals.png", robot, data, result, coulomb)
        if model_file and result.drive is not None and result.drive.layout.count:
            (tmp / "drive_effects.yaml").write_text(drive_effects_yaml(result.drive))
            model_file_extra = ["drive_effects.yaml"]
        else:
            model_file_extra = []
    if note:
        print(note)
    written = ["identified.json", "residuals.png"] + ([model_file] if model_file else []) + model_file_extra
    remove_stale_outputs(out, IDENTIFY_OUTPUTS, written)  # e.g. an earlier run's model.urdf
    print(f"wrote {out}/" + ", ".join(written))
    return 0


def _print_data_summary(args: argparse.Namespace, robot, raw, data) -> None:
    """The robot, the raw data and what preprocessing did to it."""
    p = data.preprocessing
    print(
        f"robot {robot.name}: {robot.n} joints; data {args.data}: {raw.num_samples} samples, "
        f"{raw.duration:.2f} s at {raw.rate_hz:.0f} Hz",
        flush=True,
    )
    if p is not None:
        grid = (f"resampled onto a uniform {p.input_rate_hz:.0f} Hz grid (the raw time steps vary), "
                if p.resampled else "")
        print(
            f"preprocessing: {grid}low-pass {p.cutoff_hz:.2f} Hz ({p.cutoff_source}), "
            f"{p.samples_out} samples at {p.rate_hz:.0f} Hz from {p.samples_in} raw rows, "
            f"{p.trim_s:.2f} s trimmed at each end "
            f"({p.duration_out_s:.2f} of {p.duration_in_s:.2f} s used), "
            f"v {p.velocity_source}, vdot {p.acceleration_source}",
            flush=True,
        )


def _print_fit_summary(method: str, robot, result) -> None:
    """Conditioning, the least determined base parameters and the residual per joint."""
    print(
        f"{method} from {result.measurement}: {result.base.count} base parameters, "
        f"cond(W) = {result.cond:.4g}, {result.wall_time:.2f} s",
        flush=True,
    )
    order = np.argsort(result.sigma_percent)
    worst = order[-min(5, len(order)) :][::-1]
    print(
        "least determined base parameters (%σ): "
        + ", ".join(f"{_short_name(result.base, i)} {format_percent(result.sigma_percent[i])}" for i in worst)
    )
    print(
        "residual RMS [N·m, N]: "
        + ", ".join(f"{c} {r:.4g}" for c, r in zip(result.channels, result.residual_rms))
    )


def _model_parameters(robot, result) -> tuple[np.ndarray | None, str]:
    """Standard parameters for model.urdf (None: none physically valid) and a note on them.

    The physical method gives them; for least squares the a-priori model is moved to the
    identified base parameters, and kept only when that is physically valid.
    """
    if result.phi is not None:
        return result.phi, ""
    candidate = standard_from_base(robot, result)
    if not validity_problems(robot.body_names, candidate):
        return candidate, "standard parameters: the a-priori model moved to the identified base parameters"
    return None, (
        "model.urdf not written: the least-squares estimate has no physically valid standard "
        "parameters near the a-priori model; use --method physical"
    )


def _short_name(base, i: int) -> str:
    """The standard parameter a base parameter is built on, '+…' when others are lumped in."""
    name = base.names[base.independent[i]]
    return name if base.base_names[i] == name else name + "+…"


def validate_command(args: argparse.Namespace) -> int:
    """Runs ``pe-drake validate``: per-channel RMS and relative error on another run.

    Any identified model predicts any channel: one identified from the ground wrench alone
    predicts the joint torques too (issue 14).
    """
    if args.json:  # before any work
        check_output_file(args.json, "--json", (".json",))
    if args.plot:
        check_output_file(args.plot, "--plot", (".png", ".pdf", ".svg"))
    config = config_from_args(args)
    measurement = measurement_from_args(args, config)
    robot = robot_from_args(args, config)
    result = load_identified(args.model, robot)  # identified.json or the diagnosis's augmented_model.json
    for note in result.physical_notes if result.method == "diagnose" else ():
        print(f"note: {note}")
    raw = read_log_from_args(args, robot, config)
    data = prepare_measurement(robot, raw, cutoff_hz=getattr(args, "cutoff", None), max_gap_s=config.data.max_gap_s)
    print_notes(data)
    check_against_model(robot, data)
    kind = MeasurementType(measurement)
    names = kind.row_names(robot.joint_names)
    scale = result.drive.layout.velocity_scale if result.drive is not None else 0.01
    measured, predicted = _channels(robot, result, data, kind, filtered_coulomb(raw, data, scale))
    rms, rel = torque_errors(measured, predicted)
    total = float(100 * np.linalg.norm(measured - predicted) / max(np.linalg.norm(measured), 1e-300))
    width = max(len(j) for j in names)
    print(f"model identified from {result.measurement}; predicting {measurement}")
    print(f"{'channel':<{width}}  {'RMS [N·m, N]':>12}  {'relative [%]':>12}")
    for j, r, e in zip(names, rms, rel):
        print(f"{j:<{width}}  {r:>12.4f}  {e:>12.2f}")
    print(f"{'all':<{width}}  {float(np.sqrt(np.mean(rms**2))):>12.4f}  {total:>12.2f}")
    report = {
        "robot": robot.name,
        "model": str(args.model),
        "model_measurement": result.measurement,
        "measurement": measurement,
        "data": str(args.data),
        "rms": dict(zip(names, map(float, rms))),
        "relative_error": dict(zip(names, map(float, rel))),
        "relative_error_total": total,
        "samples": data.num_samples,
    }
    if args.json:
        atomic_write_text(args.json, json.dumps(report, indent=2))
        print(f"wrote {args.json}")
    if args.plot:
        _plot_prediction(Path(args.plot), robot, data.t, measured, predicted, rel, names)
        print(f"wrote {args.plot}")
    return 0


def _channels(robot, result, data, kind: MeasurementType, coulomb=None) -> tuple[np.ndarray, np.ndarray]:
    """(measured, predicted), each (S, r): the joint torques, then the ground wrench
    (``coulomb``: the parallel-filtered Coulomb columns of the drive terms)."""
    measured_values(robot, data, kind.kind)  # refuses data without the channels, naming them
    measured, predicted = [], []
    if kind.torques:
        measured.append(data.tau)
        predicted.append(predict(robot, result, data, coulomb=coulomb))
    if kind.wrench:
        measured.append(data.wrench)
        predicted.append(predict_wrench(robot, result, data))
    return np.hstack(measured), np.hstack(predicted)


def _plot_residuals(path: Path, robot, data, result, coulomb=None) -> None:
    """Measured channels and the model's fit on the identification data."""
    measured, predicted = _channels(robot, result, data, MeasurementType(result.measurement), coulomb)
    title = f"{robot.name}: {result.method} fit on the identification data"
    _plot_prediction(path, robot, data.t, measured, predicted, result.relative_error, result.channels, title)


def _plot_prediction(path: Path, robot, t, measured, predicted, rel, names, title: str = "") -> None:
    import matplotlib  # lazy: matplotlib is heavy and only needed for the plot

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = measured.shape[1]
    fig, axes = plt.subplots(n, 1, figsize=(11, 1.7 * n + 1), sharex=True, constrained_layout=True)
    axes = np.atleast_1d(axes)
    for j, ax in enumerate(axes):
        ax.plot(t, measured[:, j], "k", lw=1, label="measured")
        ax.plot(t, predicted[:, j], "C1", lw=1, label="model")
        ax.plot(t, measured[:, j] - predicted[:, j], "C3", lw=0.7, alpha=0.7, label="error")
        unit = "N" if names[j].startswith("wrench.f") else "N·m"
        ax.set_ylabel(f"{names[j]}\n[{unit}]", fontsize=7)
        ax.set_title(f"relative error {rel[j]:.1f} %", fontsize=8, loc="right")
    axes[0].legend(fontsize=7, ncol=3, loc="upper left")
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(title or f"{robot.name}: measured vs predicted")
    save_figure(fig, path)


