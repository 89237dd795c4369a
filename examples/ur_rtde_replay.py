"""Replay an optimized trajectory on a Universal Robots arm with ur_rtde and log it for identification.

UNTESTED ON HARDWARE. Written against ur_rtde's documented API (RTDEControlInterface.servoJ,
RTDEReceiveInterface.startFileRecording); it has never been run on a robot. Read it, run it
first in URSim, keep the teach pendant's emergency stop at hand, and start with a slowed-down
copy of the trajectory. The test suite only compiles this file.

Design → run → log → identify:

    pe-drake optimize --robot ur5 --csv-rate 500 --out results/ur5      # trajectory.csv at 500 Hz
    pip install ur_rtde
    python examples/ur_rtde_replay.py --host 192.168.1.10 --csv results/ur5/trajectory.csv --log run1.csv
    pe-drake identify --robot ur5 --config my_ur5.yaml --data run1.csv  # my_ur5.yaml: robot.drive_gains

The log has UR's column names (timestamp, actual_q_0..5, actual_qd_0..5, actual_current_0..5),
which ``pe-drake identify`` recognises; motor currents need ``robot.drive_gains`` [N·m/A].
"""

from __future__ import annotations

import argparse
import csv
import sys

#: What the recorder logs: positions, velocities, motor currents (never actual_current_as_torque:
#: it is gravity-compensated and identifies nothing).
RECORDED = ["timestamp", "actual_q", "actual_qd", "actual_current"]


def read_trajectory_csv(path: str) -> tuple[list[float], list[list[float]]]:
    """(t [s], q rows [rad]) of pe_drake's trajectory.csv (columns t, q.<joint>, ...)."""
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    header, data = rows[0], rows[1:]
    q_cols = [k for k, name in enumerate(header) if name.startswith("q.")]
    if len(q_cols) != 6:
        raise SystemExit(f"{path}: expected 6 q.<joint> columns for a UR arm, found {len(q_cols)}")
    return [float(r[0]) for r in data], [[float(r[k]) for k in q_cols] for r in data]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--host", required=True, help="robot (or URSim) IP address")
    parser.add_argument("--csv", required=True, help="pe_drake trajectory.csv (written with --csv-rate 500)")
    parser.add_argument("--log", required=True, help="RTDE log to write")
    parser.add_argument("--lookahead", type=float, default=0.05, help="servoJ lookahead time [s] (0.03-0.2)")
    parser.add_argument("--gain", type=float, default=500, help="servoJ gain (100-2000)")
    args = parser.parse_args(argv)

    import rtde_control  # ur_rtde; not a pe_drake dependency
    import rtde_receive

    t, q = read_trajectory_csv(args.csv)
    dt = t[1] - t[0]
    control = rtde_control.RTDEControlInterface(args.host)
    receive = rtde_receive.RTDEReceiveInterface(args.host, 1.0 / dt)
    try:
        control.moveJ(q[0], 0.3, 0.5)  # slowly to the trajectory's start, at rest
        receive.startFileRecording(args.log, RECORDED)
        for row in q:
            start = control.initPeriod()
            control.servoJ(row, 0.0, 0.0, dt, args.lookahead, args.gain)
            control.waitPeriod(start)
        control.servoStop()
    finally:
        receive.stopFileRecording()
        control.stopScript()
    print(f"wrote {args.log}: identify with pe-drake identify --robot ur5 --data {args.log}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
