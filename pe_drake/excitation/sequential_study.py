"""The paper's sequential study (Ayusawa et al., ICRA 2017, section IV-B, Tables I and II).

Three (or more) motions optimized one after the other, motion i with the regressors of
motions 1..i-1 as prior data C0 (Eq. 41), next to the conventional method of reference
[16]: random motions that meet the same constraints, selected greedily. The study on the
Unitree G1's arms (examples/humanoid_g1_arms.py) is a thin script over
:func:`run_sequential_study`; the result writes tables.json, tables.md and the trajectories.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pe_drake.exceptions import ConfigError
from pe_drake.excitation.baseline import generate_candidates, greedy_select
from pe_drake.excitation.constraints import constraints_from_config
from pe_drake.excitation.parallel import ExecutorOptions, open_executor
from pe_drake.excitation.sequential import SequenceOptions, optimize_sequence
from pe_drake.excitation.trajectory_file import save_trajectory
from pe_drake.io_utils import atomic_write_text
from pe_drake.multibody.registry import resolve_robot_config
from pe_drake.multibody.robot import Robot

# HRP-4 figures of the paper (Tables I and II).
PAPER_TABLE_I = {"cond_motion": [47.6, 114.2, 125.5], "cond_total": [47.6, 35.7, 33.9]}
PAPER_TABLE_II = {"cond_motion": [274.1, 332.0, 436.2], "cond_total": [274.1, 156.3, 124.7]}
PAPER_RATIO = PAPER_TABLE_II["cond_motion"][0] / PAPER_TABLE_I["cond_motion"][0]  # 5.76
RATIO_TARGET = 6.0  # baseline best first motion / optimized first motion
TIME_TARGET = 120.0  # wall time per motion on 2 cores [s]

#: Seeds of the baseline's draws at amplitude k start at BASELINE_SEED + k·BASELINE_SEED_BLOCK
#: (+ --seed), apart from each other and from the optimizer's start seeds (--seed + 1000·(i-1)).
BASELINE_SEED = 1_000_000
BASELINE_SEED_BLOCK = 100_000


@dataclasses.dataclass(frozen=True)
class StudyOptions:
    """What one study does; :data:`FULL` and :data:`QUICK` hold the example's defaults."""

    config: Path | None = None  # YAML file overriding models/<robot>.yaml
    motions: int = 3
    starts: int = 2  # random initial points per motion
    workers: int = 2  # starts (and chunks of baseline draws) at once
    executor: str = "local"  # "local" (process pool) or "ray"
    ray_address: str = ""  # Ray cluster ("": ray.init()'s default)
    max_iterations: int | None = 150  # IPOPT iterations per start (None: the config's)
    max_time: float = 0.0  # wall-time limit per start [s]; 0: none
    criterion: str | None = None  # None: the config's (soft_cond)
    amplitude: float | None = None  # scale of the optimizer's random initial points [rad]
    candidates: int = 100  # accepted random motions per baseline amplitude
    baseline_amplitudes: tuple[float, ...] = (0.1, 0.125, 0.15)  # [rad]
    seed: int = 0
    quick: bool = False
    robot: str = "g1"

    def __post_init__(self) -> None:
        for name in ("motions", "starts", "workers", "candidates"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ConfigError(f"sequential study: {name} must be a positive integer, got {value!r}")
        if self.executor not in ("local", "ray"):
            raise ConfigError(f"sequential study: executor must be 'local' or 'ray', got {self.executor!r}")
        if not all(math.isfinite(a) and a > 0 for a in self.baseline_amplitudes):
            raise ConfigError(f"sequential study: baseline amplitudes must be positive, got {list(self.baseline_amplitudes)}")
        if len(set(self.baseline_amplitudes)) != len(self.baseline_amplitudes):
            raise ConfigError(f"--baseline-amplitudes must differ, got {list(self.baseline_amplitudes)}")
        if self.candidates * len(self.baseline_amplitudes) < self.motions:
            raise ConfigError(f"--candidates {self.candidates} × {len(self.baseline_amplitudes)} "
                              f"amplitude(s) cannot supply {self.motions} baseline motions")


# IPOPT ≤ 150 iterations keeps a motion within about 2 minutes on 2 cores (README, "Reproducing
# the paper on G1"); larger baseline amplitudes are rejected far more often (balance, collision).
FULL = {"starts": 2, "workers": 2, "candidates": 100, "baseline_amplitudes": (0.1, 0.125, 0.15),
        "max_iterations": 150}
QUICK = {"starts": 1, "workers": 1, "candidates": 8, "baseline_amplitudes": (0.05, 0.1), "max_iterations": 15}


def _running_sigmas(blocks: Sequence[np.ndarray]) -> tuple[list[float], list[float]]:
    """σ_min and σ_max of [B_1; ...; B_i] for i = 1, 2, ...

    Both are non-decreasing in i: CᵀC = Σ B_kᵀB_k (Eq. 41) only gains a positive
    semidefinite term, so no eigenvalue of it falls (Weyl). cond = σ_max/σ_min may still rise.
    """
    s = [np.linalg.svd(np.vstack(blocks[:i]), compute_uv=False) for i in range(1, len(blocks) + 1)]
    return [float(x[-1]) for x in s], [float(x[0]) for x in s]


class StudyPrinter:
    """Progress lines; the baseline's per-chunk events are thinned to one every few seconds."""

    def __init__(self, say: Callable[[str], Any] | None, every: float = 5.0):
        self.say, self.every, self.last = say, every, -math.inf
        #: 1-minute load average when each motion finished: wall times depend on it
        self.loads: list[float] = []

    def __call__(self, text: str) -> None:
        if self.say is not None:
            self.say(text)

    def event(self, event) -> None:
        if getattr(event, "kind", "") == "finished" and hasattr(event, "motion"):
            self.loads.append(os.getloadavg()[0] if hasattr(os, "getloadavg") else math.nan)
        self(str(event))

    def draws(self, event) -> None:
        now = time.perf_counter()
        if now - self.last >= self.every or event.accepted >= event.wanted:
            self.last = now
            self(str(event))


def _constraints_text(excitation) -> str:
    """The sampled constraints of the run, in words (Eqs. 52, 53)."""
    parts = ["joint limits"]
    if excitation.balance_radius > 0:
        parts.append(f"balance r = {excitation.balance_radius * 100:.3g} cm")
    if excitation.collision_margin >= 0:
        parts.append(f"capsule margin {excitation.collision_margin * 100:.3g} cm")
    return ", ".join(parts)


def run_sequential_study(settings: StudyOptions, *, say: Callable[[str], Any] | None = None) -> SequentialStudy:
    """Runs the optimization and the baseline; ``say`` gets the progress lines (None: silent).

    Raises:
        ConfigError, UnknownNameError: a bad config file or value.
        InfeasibleError: too few feasible random motions, or an infeasible nominal posture.
        WorkerError: a start or a chunk of draws failed in a worker, or its worker died.
    """
    say = StudyPrinter(say)
    begin = time.perf_counter()
    config = resolve_robot_config(settings.robot, settings.config)
    excitation = config.excitation
    if settings.criterion:
        excitation = dataclasses.replace(excitation, criterion=settings.criterion)
    solver = dataclasses.replace(
        config.solver, verbose=False, max_time=settings.max_time or config.solver.max_time,
        max_iterations=settings.max_iterations or config.solver.max_iterations)
    robot = Robot(settings.robot, config.robot)
    workers = settings.workers
    executor = open_executor(robot, settings.executor, workers, address=settings.ray_address,
                             constraints_factory=constraints_from_config)
    base = executor.base
    period = 2 * math.pi / excitation.omega
    say(
        f"{settings.robot.upper()}: {robot.n} arm joints, {base.count} base parameters; N = {excitation.harmonics}, "
        f"ω = {excitation.omega:.4g} rad/s (period {period:.3g} s), T = {excitation.cost_samples} "
        f"({period / excitation.cost_samples:.3g} s apart), K = {excitation.constraint_samples} "
        f"({period / excitation.constraint_samples:.3g} s apart), {_constraints_text(excitation)}; "
        f"criterion {excitation.criterion}"
    )
    say(
        f"{settings.motions} motions × {settings.starts} start(s) on {workers} {settings.executor} worker(s), "
        f"{solver.name} ≤ {solver.max_iterations} iterations per start" + ("  [quick]" if settings.quick else "")
    )
    try:
        sets, candidates, selection, baseline_time = _baseline(settings, robot, excitation, executor, say)

        # ---- Table I: sequential optimization (section IV-B): motion i minimizes cond of
        # [C^(1); ...; C^(i-1); C^(i)], the earlier blocks being fixed prior data C0 (Eq. 41).
        interval = 10.0 if not settings.quick else 5.0
        sequence = optimize_sequence(robot, excitation, solver, SequenceOptions(
            settings.motions, starts=settings.starts, seed=settings.seed, amplitude=settings.amplitude,
            stop_on_failure=False, run=ExecutorOptions(executor=executor, progress_interval=interval)),
            progress=say.event)
    finally:
        executor.close()

    problem = executor.problem(excitation)
    baseline_blocks = [problem.regressor_block(candidates[k][1].alpha) for k in selection.indices]
    tables = _tables(settings, excitation, solver, robot, base, sequence, selection, candidates, sets, baseline_blocks)
    tables["timing"]["baseline_generation_s"] = baseline_time
    tables["timing"]["total_s"] = time.perf_counter() - begin
    tables["timing"]["load_average_1min_after_motion"] = say.loads
    tables["timing"]["cpu_count"] = os.cpu_count()
    return SequentialStudy(tables, robot, problem, sequence, selection, candidates)


def _baseline(settings: StudyOptions, robot: Robot, excitation, executor, say):
    """Table II: random motions under the same constraints, greedy selection ([16])."""
    say(f"baseline: {settings.candidates} feasible random motions at each amplitude "
        + ", ".join(f"{a:g}" for a in settings.baseline_amplitudes) + " rad")
    sets = []  # (amplitude, CandidateSet)
    for k, amplitude in enumerate(settings.baseline_amplitudes):
        cset = generate_candidates(robot, excitation, settings.candidates,
                                   seed=BASELINE_SEED + k * BASELINE_SEED_BLOCK + settings.seed,
                                   amplitude=amplitude, max_draws=400 * settings.candidates,
                                   executor=executor, progress=say.draws)
        conds = np.array([c.cond for c in cset.candidates])
        say(f"  amplitude {amplitude:g} rad: {len(conds)} accepted of {cset.draws} draws, "
            f"cond min {conds.min():.4g}, median {np.median(conds):.4g}, {cset.wall_time:.1f} s")
        sets.append((amplitude, cset))
    candidates = [(a, c) for a, cset in sets for c in cset.candidates]
    selection = greedy_select([r for _, cset in sets for r in cset.R], settings.motions)
    return sets, candidates, selection, sum(cset.wall_time for _, cset in sets)


def _tables(settings, excitation, solver, robot: Robot, base, sequence, selection, candidates, sets, baseline_blocks) -> dict:
    motions = sequence.motions
    opt_lo, opt_hi = _running_sigmas([m.block for m in motions])
    bl_lo, bl_hi = _running_sigmas(baseline_blocks)
    first_opt, first_base = motions[0].cond_motion, selection.cond_each[0]
    times = [m.wall_time for m in motions]
    period = 2 * math.pi / excitation.omega
    return {
        "paper": "K. Ayusawa et al., Generating persistently exciting trajectory based on condition "
        "number optimization, ICRA 2017, section IV-B, Tables I and II (HRP-4)",
        "robot": robot.name, "joints": list(robot.joint_names), "quick": settings.quick,
        "setting": {
            "harmonics": excitation.harmonics, "omega": excitation.omega, "period_s": period,
            "cost_samples": excitation.cost_samples,
            "cost_sample_spacing_s": period / excitation.cost_samples,
            "constraint_samples": excitation.constraint_samples,
            "constraint_sample_spacing_s": period / excitation.constraint_samples,
            "balance_radius_m": excitation.balance_radius,
            "collision_margin_m": excitation.collision_margin,
            "constraints": _constraints_text(excitation), "criterion": excitation.criterion,
            "base_parameters": base.count, "variables": (2 * excitation.harmonics + 1) * robot.n,
            "solver": solver.name, "max_iterations": solver.max_iterations,
            "max_time_s": solver.max_time, "motions": settings.motions, "starts": settings.starts,
            "workers": sequence.workers, "executor": settings.executor, "seed": settings.seed,
        },
        "table1": {
            "motion": [m.index for m in motions], "cond_motion": [m.cond_motion for m in motions],
            "cond_total": [m.cond_total for m in motions], "sigma_min_total": opt_lo,
            "sigma_max_total": opt_hi, "success": [m.success for m in motions],
            "message": [m.result.message for m in motions], "seed": [m.seed for m in motions],
            "wall_time_s": times,
            "starts": [[dataclasses.asdict(s) for s in m.starts] for m in motions],
            "paper_hrp4": PAPER_TABLE_I,
        },
        "table2": {
            "motion": list(range(1, len(selection.indices) + 1)),
            "cond_motion": list(selection.cond_each), "cond_total": list(selection.cond_total),
            "sigma_min_total": bl_lo, "sigma_max_total": bl_hi,
            "seed": [candidates[k][1].seed for k in selection.indices],
            "amplitude": [candidates[k][0] for k in selection.indices],
            "candidates": len(candidates),
            "per_amplitude": [
                {"amplitude": a, "accepted": len(cset.candidates), "draws": cset.draws, "rejected": cset.rejected,
                 "cond_min": float(min(c.cond for c in cset.candidates)),
                 "cond_median": float(np.median([c.cond for c in cset.candidates])), "wall_time_s": cset.wall_time}
                for a, cset in sets
            ],
            "paper_hrp4": PAPER_TABLE_II,
        },
        "ratio_first_motion": {"baseline": first_base, "optimized": first_opt, "ratio": first_base / first_opt,
                               "target": RATIO_TARGET, "paper": PAPER_RATIO},
        "timing": {"wall_time_per_motion_s": times, "target_per_motion_s": TIME_TARGET},
        "success": sequence.success,
    }


@dataclasses.dataclass
class SequentialStudy:
    """Tables I and II of one study and what produced them; :meth:`write` puts them in a folder."""

    tables: dict  # the content of tables.json ("files" is added by write)
    robot: Robot
    problem: Any  # ExcitationProblem of the run (turns the baseline's coefficients into trajectories)
    sequence: Any  # SequenceResult of optimize_sequence
    selection: Any  # greedy selection of the baseline candidates
    candidates: list  # (amplitude, Candidate) of every accepted random motion

    @property
    def success(self) -> bool:
        return bool(self.tables["success"])

    def markdown(self) -> str:
        return format_markdown(self.tables)

    def console(self) -> str:
        return format_console(self.tables)

    def write(self, out: Path | str) -> list[str]:
        """Trajectories first (none for a motion that violates a constraint), the tables last,
        each file written atomically; returns the files."""
        out = Path(out)
        files = []
        for m in self.sequence.motions:
            if not m.success:
                continue
            path = out / f"motion_{m.index}" / "trajectory.json"
            save_trajectory(path, self.robot, m.result.trajectory, cond=m.cond_total,
                            cond_motion=m.cond_motion, motion=m.index)
            files.append(str(path.relative_to(out)))
        for i, k in enumerate(self.selection.indices, start=1):
            amplitude, cand = self.candidates[k]
            path = out / f"baseline_{i}" / "trajectory.json"
            save_trajectory(path, self.robot, self.problem.trajectory(cand.alpha),
                            cond=self.selection.cond_total[i - 1], cond_motion=cand.cond, motion=i,
                            baseline_seed=cand.seed, baseline_amplitude=amplitude)
            files.append(str(path.relative_to(out)))
        self.tables["files"] = files
        atomic_write_text(out / "tables.json", json.dumps(self.tables, indent=2) + "\n")
        atomic_write_text(out / "tables.md", format_markdown(self.tables))
        return files


def _cond_rows(table: dict, paper: dict) -> list[str]:
    """A table's rows of cond(C^(i)) and cond(C), ours against the paper's, and σ_min(C)."""
    return [_md_row("cond(C^(i)), G1", table["cond_motion"]), _md_row("cond(C^(i)), paper HRP-4", paper["cond_motion"]),
            _md_row("cond(C), G1", table["cond_total"]), _md_row("cond(C), paper HRP-4", paper["cond_total"]),
            _md_row("σ_min(C), G1", table["sigma_min_total"], "{:.4g}")]


def _md_row(label: str, values: Sequence[float], fmt: str = "{:.1f}") -> str:
    return f"| {label} | " + " | ".join(fmt.format(v) for v in values) + " |"


def format_markdown(t: dict) -> str:
    """tables.md: Tables I and II next to the paper's HRP-4 figures."""
    s, t1, t2, r = t["setting"], t["table1"], t["table2"], t["ratio_first_motion"]
    n = len(t1["motion"])
    head = "| motion index | " + " | ".join(str(i) for i in t1["motion"]) + " |\n|---|" + "---|" * n
    paper1 = {k: v[:n] for k, v in t1["paper_hrp4"].items()}
    paper2 = {k: v[:n] for k, v in t2["paper_hrp4"].items()}
    lines = [
        "# Ayusawa et al. (ICRA 2017), Tables I and II, on the Unitree G1" + (" (quick run)" if t["quick"] else ""),
        "",
        f"G1, {len(t['joints'])} arm joints, {s['base_parameters']} base parameters; N = {s['harmonics']}, "
        f"ω = {s['omega']:.4g} rad/s (period {s['period_s']:.3g} s), T = {s['cost_samples']} cost samples "
        f"{s['cost_sample_spacing_s']:.3g} s apart, K = {s['constraint_samples']} constraint samples "
        f"{s['constraint_sample_spacing_s']:.3g} s apart; {s['constraints']}; criterion {s['criterion']}, "
        f"{s['solver']} ≤ {s['max_iterations']} iterations, {s['starts']} start(s) per motion in "
        f"{s['workers']} {s.get('executor', 'local')} worker(s), seed {s['seed']}.",
        "",
        "## Table I: optimized motions (motion i optimized with C0 = motions 1..i-1)",
        "",
        head,
        *_cond_rows(t1, paper1),
        _md_row("wall time [s], G1", t1["wall_time_s"]),
        "| constraints met (1 kHz) | " + " | ".join("yes" if ok else "NO" for ok in t1["success"]) + " |",
        "",
        f"## Table II: random motions, greedy selection (reference [16]; {t2['candidates']} feasible candidates)",
        "",
        head,
        *_cond_rows(t2, paper2),
        "",
        "| amplitude [rad] | accepted / draws | cond min | cond median |",
        "|---|---|---|---|",
    ]
    for p in t2["per_amplitude"]:
        lines.append(f"| {p['amplitude']:g} | {p['accepted']} / {p['draws']} | {p['cond_min']:.4g} | {p['cond_median']:.4g} |")
    lines += [
        "",
        f"Baseline best first motion / optimized first motion: {r['baseline']:.4g} / {r['optimized']:.4g} = "
        f"**{r['ratio']:.2f}×** (target ≥ {r['target']:g}×; paper 274.1 / 47.6 = {r['paper']:.2f}×).",
        "",
        "Wall time per motion: "
        + ", ".join(f"{x:.1f} s" for x in t["timing"]["wall_time_per_motion_s"])
        + f" (target ≤ {t['timing']['target_per_motion_s']:.0f} s); baseline generation "
        f"{t['timing'].get('baseline_generation_s', math.nan):.1f} s; "
        f"total {t['timing'].get('total_s', math.nan):.1f} s.",
    ]
    loads = t["timing"].get("load_average_1min_after_motion")
    if loads:
        lines.append("1-minute load average after each motion: "
                     + ", ".join(f"{x:.2f}" for x in loads) + f" on {t['timing'].get('cpu_count')} "
                     "cores (other jobs slow the solves down).")
    return "\n".join(lines + [""])


def format_console(t: dict) -> str:
    """Tables I and II side by side with the paper, for the terminal."""
    t1, t2, r = t["table1"], t["table2"], t["ratio_first_motion"]
    n = len(t1["motion"])
    idx = "".join(f"{i:>10d}" for i in t1["motion"])

    def row(label, values, fmt="{:>10.1f}"):
        return f"  {label:<30s}" + "".join(fmt.format(v) for v in values)

    def cond_rows(table):
        paper = table["paper_hrp4"]
        return [("cond(C^(i))  G1", table["cond_motion"]), ("             paper HRP-4", paper["cond_motion"][:n]),
                ("cond(C)      G1", table["cond_total"]), ("             paper HRP-4", paper["cond_total"][:n])]

    out = [
        "",
        f"Table I: optimized (sequential)   motion{idx}",
        *(row(label, values) for label, values in cond_rows(t1)),
        row("wall time [s] G1", t1["wall_time_s"]),
        f"Table II: random + greedy         motion{idx}",
        *(row(label, values) for label, values in cond_rows(t2)),
        "",
        f"first motion, baseline / optimized: {r['baseline']:.4g} / {r['optimized']:.4g} = {r['ratio']:.2f}x "
        f"(target >= {r['target']:g}x: {'met' if r['ratio'] >= r['target'] else 'MISSED'}; "
        f"paper {r['paper']:.2f}x)",
        "wall time per motion: " + ", ".join(f"{x:.1f} s" for x in t1["wall_time_s"])
        + f" (target <= {TIME_TARGET:.0f} s: "
        + ("met" if max(t1["wall_time_s"]) <= TIME_TARGET else "MISSED") + ")",
    ]
    totals = t1["cond_total"]
    if len(totals) > 1:
        falls = all(b < a for a, b in zip(totals, totals[1:]))
        out.append("cond(C) after each motion: " + " -> ".join(f"{x:.4g}" for x in totals)
                   + f" (target: falls with each motion: {'met' if falls else 'MISSED'})")
    if not all(t1["success"]):
        out.append("WARNING: motions "
                   + ", ".join(str(i) for i, ok in zip(t1["motion"], t1["success"]) if not ok)
                   + " violate a constraint (no trajectory.json written for them)")
    return "\n".join(out)


