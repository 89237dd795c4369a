"""Diagnose the a-priori Panda model against a real Franka Emika Panda recording.

Reads ../shared/datasets/panda_gaz2019/excitation_1.csv (Gaz et al., RA-L 2019; not part of
this project: skipped with a message when the folder is absent), compares the Panda model of
example-robot-data with it, re-identifies the rigid-body parameters on the first 70 % of the
run, names the effects the model misses and shows how much of the gap they close on the last
30 %, held out. Writes what ``pe-drake diagnose`` writes into --out.

    python examples/diagnose_real_panda.py [--data FILE] [--out results/diagnose_real_panda]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_DATA = ROOT.parent / "shared" / "datasets" / "panda_gaz2019" / "excitation_1.csv"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(DEFAULT_DATA), help="measurement CSV")
    parser.add_argument("--out", default="results/diagnose_real_panda", help="output folder")
    args = parser.parse_args(argv)
    if not Path(args.data).is_file():
        print(f"skipped: the real Panda recording is not here ({args.data}); pass --data FILE; it is not part of the "
              "project (see ../shared/datasets/panda_gaz2019/README.md)")
        return 0

    from pe_drake.diagnosis import diagnose
    from pe_drake.identification import read_measurements
    from pe_drake.multibody.robot import load_robot
    from pe_drake.threads import single_threaded_blas

    robot = load_robot("panda")
    data = read_measurements(robot, args.data)  # the door: read and checked as `pe-drake diagnose` does
    with single_threaded_blas():
        result = diagnose(robot, data, progress=lambda s: print(s, flush=True))
        result.write(args.out)

    print()
    print("named per joint:")
    for name in robot.joint_names:
        effects = [f"{e.effect} {e.value:+.3g} {e.unit}" for e in result.effects if e.joint == name]
        print(f"  {name}: {', '.join(effects) or '-'}")
    for e in result.effects:
        if e.effect == "payload":
            print(f"  payload on {e.link}: {e.value:+.3g} kg")
    pt = result.payload_test
    print(f"payload search (best link {pt.get('best_link', '-')}): {pt.get('decision', '')}")
    print()
    print(f"{'joint':14s} {'a-priori':>9s} {'rigid':>9s} {'augmented':>9s}  gap closed   held-out RMS [N·m]")
    for j, name in enumerate(robot.joint_names):
        a, b, c = result.rms_nominal[j], result.rms_rigid[j], result.rms_after[j]
        print(f"{name:14s} {a:9.3f} {b:9.3f} {c:9.3f}  {100 * (1 - (c / a) ** 2):6.1f} %   "
              + ("unexplained" if name in result.unexplained else ""))
    sign_v = {j: result.regimes[j]["correlation_sign_v"] for j in robot.joint_names}
    print("a-priori residual vs sign(v): " + ", ".join(f"{j[-1]} {c:+.2f}" for j, c in sign_v.items()))
    means = {j: result.regimes[j]["overall"]["mean"] for j in robot.joint_names}
    print("a-priori residual mean [N·m]: " + ", ".join(f"{j[-1]} {m:+.2f}" for j, m in means.items()))
    print(f"wrote {args.out}/report.md, diagnosis.json, figures and the augmented model")
    return 0


if __name__ == "__main__":
    sys.exit(main())
