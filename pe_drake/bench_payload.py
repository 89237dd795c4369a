"""``python -m pe_drake.bench payload``: payload excitation and identification, timed, with errors
for random box payloads on a true arm that differs from its URDF: the paired fit (loaded and
unloaded runs) and the loaded run alone.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from pe_drake.excitation.payload_motion import optimize_payload_motion
from pe_drake.identification.payload import identify_payload, payload_errors
from pe_drake.identification.payload_formats import default_flange
from pe_drake.multibody.robot import load_robot
from pe_drake.simulation.payload_synthetic import payload_run, random_box_payload, random_true_arm
from pe_drake.threads import single_threaded_blas


def bench_payload(args: argparse.Namespace) -> None:
    """Prints the excitation time, the identification time and the errors per payload."""
    robot = load_robot(args.robot)
    link = getattr(args, "link", "") or default_flange(robot)
    count = max(1, int(getattr(args, "payloads", 5)))
    with single_threaded_blas():
        t0 = time.perf_counter()
        plan = optimize_payload_motion(robot, link)
        t_exc = time.perf_counter() - t0
    print(f"robot {robot.name}, payload link {link}: motion {plan.motion.duration:.3g} s (ramps "
          f"{plan.motion.ramp_duration:g} s each), criterion {plan.result.fun:.4g}, cond(Y_L) {plan.result.cond:.4g}, "
          f"optimized in {t_exc:.2f} s ({plan.result.nit} iterations)")
    for line in plan.expected.summary_lines():
        print(line)
    rng = np.random.default_rng(args.seed)
    rows, times = [], []
    for k in range(count):
        arm, payload, noise = random_true_arm(robot, rng), random_box_payload(rng), rng.uniform(0.03, 0.05)
        loaded = payload_run(robot, plan.motion, arm, link, payload, noise_std=noise, seed=2 * k)
        empty = payload_run(robot, plan.motion, arm, link, None, rate_hz=800.0, t0=4e-4, noise_std=noise, seed=2 * k + 1)
        t0 = time.perf_counter()
        paired = payload_errors(identify_payload(robot, [loaded], [empty], link), payload)
        times.append(time.perf_counter() - t0)
        alone = payload_errors(identify_payload(robot, [loaded], [], link), payload)
        rows.append((paired, alone))
        sig = max(paired["mass_sigmas"], paired["com_sigmas"], paired["inertia_sigmas"])
        print(f"payload {k}: {payload.mass:.3f} kg, CoM {np.round(payload.com, 3).tolist()} m, noise {noise:.3f} N·m | "
              f"paired: mass {paired['mass_percent']:.3g} %, CoM {paired['com_m'] * 1e3:.3g} mm, inertia "
              f"{paired['inertia_percent_of_max']:.3g} % of max (max {sig:.2g} σ) | "
              f"loaded alone: mass {alone['mass_percent']:.3g} %, CoM {alone['com_m'] * 1e3:.3g} mm, inertia "
              f"{alone['inertia_percent_of_max']:.3g} %")
    worst = {key: max(r[0][key] for r in rows) for key in rows[0][0]}
    worst_alone = {key: max(r[1][key] for r in rows) for key in rows[0][1]}
    print("targets (paired): mass < 0.5 %, CoM < 1 mm, inertia < 10 % of the largest principal moment, within 3σ")
    print(f"BENCH robot={robot.name} excitation_s={t_exc:.2f} identify_s={float(np.median(times)):.2f} "
          f"mass_percent={worst['mass_percent']:.4f} com_mm={worst['com_m'] * 1e3:.4f} "
          f"inertia_percent={worst['inertia_percent_of_max']:.3f} max_sigmas="
          f"{max(worst['mass_sigmas'], worst['com_sigmas'], worst['inertia_sigmas']):.2f} "
          f"alone_mass_percent={worst_alone['mass_percent']:.3f} alone_com_mm={worst_alone['com_m'] * 1e3:.3f} "
          f"alone_inertia_percent={worst_alone['inertia_percent_of_max']:.2f}")
