"""Writes a joint-side log (t, q.<joint>, tau.<joint>) as the motor side a drive records:
q_motor = R q and tau_motor = R^-T tau, R from the config's robot.transmission.

    python examples/motor_side_log.py --robot ur5 --config examples/ur5_tx40.yaml tx/run.csv tx/run_motor.csv

``pe-drake identify`` with the same config reads it back on the joint side (README, "Drivetrains").
"""

from __future__ import annotations

import argparse

import numpy as np

from pe_drake.identification.readers import read_log
from pe_drake.multibody.robot import load_robot
from pe_drake.multibody.transmission import robot_transmission


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", required=True)
    parser.add_argument("--config", required=True, help="YAML with robot.transmission")
    parser.add_argument("joint_log")
    parser.add_argument("motor_log")
    args = parser.parse_args()
    robot = load_robot(args.robot, args.config)
    T = robot_transmission(robot)
    log = read_log(args.joint_log, robot)
    header = ["t"] + [f"q_motor.{j}" for j in robot.joint_names] + [f"tau_motor.{j}" for j in robot.joint_names]
    table = np.column_stack([log.t, T.motor_positions(log.q), T.motor_torques(log.tau)])
    np.savetxt(args.motor_log, table, delimiter=",", header=",".join(header), comments="", fmt="%.10g")
    print(f"wrote {args.motor_log}: {len(log.t)} samples of {len(robot.joint_names)} motors (R = {T.R.tolist()})")


if __name__ == "__main__":
    main()
