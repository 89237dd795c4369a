"""Identify a real Franka Emika Panda from its measured excitation run.

Reads ../shared/datasets/panda_gaz2019/excitation_1.csv (Gaz et al., RA-L 2019; not part of
this project: skipped with a message when the folder is absent), identifies the rigid-body
base parameters on the first half (OLS, WLS, physically consistent), and predicts the second
half, next to the a-priori URDF of example-robot-data. What rigid-body identification cannot
explain (friction above all) is left for ``pe-drake diagnose``.

    python examples/real_panda.py [--data FILE] [--out results/real_panda]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_DATA = ROOT.parent / "shared" / "datasets" / "panda_gaz2019" / "excitation_1.csv"


def split(data, fraction: float):
    """The data cut in two contiguous parts at ``fraction`` of its samples."""
    k = int(data.num_samples * fraction)
    fields = ("t", "q", "tau", "v", "vd")
    return (data.replace(**{f: getattr(data, f)[:k] for f in fields}), data.replace(**{f: getattr(data, f)[k:] for f in fields}))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(DEFAULT_DATA), help="measurement CSV")
    parser.add_argument("--out", default="results/real_panda", help="output folder")
    args = parser.parse_args(argv)
    if not Path(args.data).is_file():
        print(
            f"skipped: the real Panda recording is not here ({args.data}); pass --data FILE; it is not part of the "
            "project (see ../shared/datasets/panda_gaz2019/README.md)"
        )
        return 0

    from pe_drake.identification.estimators import identify
    from pe_drake.identification.intake import prepare_measurement
    from pe_drake.identification.prediction import predict, robot_torques, torque_errors
    from pe_drake.identification import read_measurements
    from pe_drake.identification.identified_file import result_to_dict
    from pe_drake.io_utils import staged_output_dir
    from pe_drake.multibody.robot import load_robot
    from pe_drake.multibody.robot_model import RobotModel
    from pe_drake.threads import single_threaded_blas

    robot = load_robot("panda")
    with single_threaded_blas():
        raw = read_measurements(robot, args.data)  # read and checked as `pe-drake identify` does
        data = prepare_measurement(robot, raw)
        p = data.preprocessing
        print(
            f"{args.data}: {raw.num_samples} samples, {raw.duration:.1f} s; low-pass {p.cutoff_hz:.2f} Hz "
            f"({p.cutoff_source}), {p.samples_out} samples at {p.rate_hz:.0f} Hz"
        )
        first, second = split(data, 0.5)
        rows = [("a-priori URDF", torque_errors(second.tau, robot_torques(robot, second, robot.phi_model)))]
        results = {}
        for method in ("ols", "wls", "physical"):
            # rigid body only, as in the README's table; the drive terms (identify's default) are in the README's drive-terms table
            results[method] = identify(robot, first, method, drive_terms="none")
            rows.append((method, torque_errors(second.tau, predict(robot, results[method], second))))
    print("\nheld-out (second half) RMS torque error [N·m] and relative error [%]")
    print(f"{'model':14s}" + "".join(f"{j[-6:]:>9s}" for j in robot.joint_names))
    for name, (rms, rel) in rows:
        print(f"{name:14s}" + "".join(f"{r:9.3f}" for r in rms))
        print(f"{'':14s}" + "".join(f"{e:8.1f}%" for e in rel))
    with staged_output_dir(args.out) as tmp:
        (tmp / "identified.json").write_text(json.dumps(result_to_dict(results["physical"], robot, "model.urdf"), indent=2))
        RobotModel(robot.joint_names, robot.body_names, results["physical"].phi).write_urdf(tmp / "model.urdf", robot)
    print(
        f"\nwrote {args.out}/identified.json, model.urdf (physically consistent). The remaining gap is "
        "mostly friction: see `pe-drake diagnose`."
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
