"""Hide effects in a simulated Panda run, then let ``diagnose`` find them.

Simulates the Panda (pe_drake.simulation.simulation) on an optimized, collision-free trajectory with
a few % inertial error, Coulomb and viscous friction on every joint, an armature, a torque
offset and a 0.8 kg payload on the hand, then diagnoses the run without knowing any of it and
prints what it named next to the truth.

    python examples/diagnose_simulated.py [--trajectory FILE] [--out results/diagnose_simulated]

The default trajectory, tests/data/diagnosis_panda_trajectory.json, was made with
``pe-drake optimize --robot panda`` and ``excitation.collision_margin: 0.03``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_TRAJECTORY = ROOT / "tests" / "data" / "diagnosis_panda_trajectory.json"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trajectory", default=str(DEFAULT_TRAJECTORY), help="trajectory.json")
    parser.add_argument("--duration", type=float, default=20.0, help="simulated time [s]")
    parser.add_argument("--out", default="results/diagnose_simulated", help="output folder")
    args = parser.parse_args(argv)

    from pe_drake.diagnosis import diagnose
    from pe_drake.excitation.trajectory_file import load_trajectory
    from pe_drake.simulation.simulation import simulate
    from pe_drake.simulation.truth import ControlTruth, NoiseTruth, make_truth
    from pe_drake.multibody.robot import load_robot
    from pe_drake.threads import single_threaded_blas

    robot = load_robot("panda")
    trajectory, _ = load_trajectory(args.trajectory)
    truth = make_truth(  # the robot as built: truth.model
        robot, {"coulomb": {"all": 0.3, "panda_joint7": 0.1}, "viscous": {"all": 0.1, "panda_joint7": 0.03},
                "armature": {"panda_joint5": 0.05}, "torque_offset": {"panda_joint2": 0.5},
                "payload": {"link": "panda_hand", "mass": 0.8, "com": [0.0, 0.0, 0.1]}},
        seed=7, inertia_perturbation=0.03, noise=NoiseTruth(encoder_counts_per_rev=524288, tau_std=0.02),
        control=ControlTruth(rate_hz=1000.0),
    )
    print(f"simulating {args.duration:g} s ...", flush=True)
    data, true = simulate(robot, trajectory, truth, args.duration)
    with single_threaded_blas():
        result = diagnose(robot, data, progress=lambda s: print(s, flush=True))
        result.write(args.out)

    tables = {"coulomb_friction": "coulomb", "viscous_friction": "viscous", "armature": "armature",
              "torque_offset": "torque_offset"}
    print()
    print(f"{'effect':18s} {'joint/link':18s} {'named':>10s} {'truth':>10s}")
    for e in result.effects:
        if e.effect == "payload":
            want = true["effects"]["payload"]["mass"]
        else:
            want = true["effects"][tables[e.effect]]["values"][e.joint]
        print(f"{e.effect:18s} {e.joint or e.link:18s} {e.value:10.4g} {want:10.4g}  {e.unit}")
    print("unexplained: " + (", ".join(result.unexplained) or "none"))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
