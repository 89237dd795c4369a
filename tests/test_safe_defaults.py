"""A robot as the user has it (issue 21): safe defaults for a model path without a config,
nothing outside a joint limit is valid, fitted capsules passed back keep their check, units
and wording of the printed lines."""

from __future__ import annotations

import dataclasses
import re
import types

import numpy as np
import pytest

from pe_drake.config import SAFE_DEFAULTS
from pe_drake.exceptions import NotWithinLimitsError
from pe_drake.excitation import optimize_motion
from pe_drake.excitation.fourier import FourierTrajectory
from pe_drake.excitation.limits import keep_strictly_inside, path_limit_bounds
from pe_drake.excitation.optimize_report import assumed_defaults
from pe_drake.excitation.problem import ExcitationProblem
from pe_drake.excitation.quality import short_composition
from pe_drake.excitation.ramp import RampedMotion, check_written_motion, choose_ramp_duration
from pe_drake.excitation.trajectory_file import write_motion_csv
from pe_drake.multibody.capsule_fitting import FITTED_COLLISION_MARGIN, with_file_margin
from pe_drake.multibody.registry import example_robot_data_dir, resolve_robot_config
from pe_drake.multibody.robot import load_robot

DEFAULTS_LINE = "defaults for a robot without a config"


def _model(relative: str) -> str:
    path = example_robot_data_dir() / "robots" / relative
    if not path.is_file():
        pytest.skip(f"example-robot-data has no {relative}")
    return str(path)


@pytest.fixture(scope="module")
def so101() -> str:
    return _model("so_arm_description/urdf/so101.urdf")


def _tiny(config, iterations: int = 3):
    """A run of a few seconds: 2 harmonics, few samples, a few IPOPT iterations."""
    return dataclasses.replace(
        config,
        excitation=dataclasses.replace(config.excitation, harmonics=2, cost_samples=12, constraint_samples=40),
        solver=dataclasses.replace(config.solver, max_iterations=iterations, verbose=False),
    )


@pytest.fixture(scope="module")
def so101_plan(so101):
    lines: list[str] = []
    plan = optimize_motion(_tiny(resolve_robot_config(so101)), progress=lines.append, name="so101")
    return plan, lines


# ---- 1. safe defaults ------------------------------------------------------------------------


def test_a_model_path_without_a_config_gets_the_shipped_robots_margins(so101):
    config = resolve_robot_config(so101)
    assert config.robot.position_margin == 0.05 and config.robot.velocity_scale == 0.8
    robot = load_robot(so101)
    # so101.urdf: shoulder_pan in [-1.91986, 1.91986] rad, 10 rad/s on every joint.
    k = robot.joint_names.index("shoulder_pan")
    assert robot.limits.q_lower[k] == pytest.approx(-1.91986 + 0.05)
    assert robot.limits.q_upper[k] == pytest.approx(1.91986 - 0.05)
    np.testing.assert_allclose(robot.limits.v_max, 8.0)
    notes = [n for n in robot.limit_notes if n.startswith(DEFAULTS_LINE)]
    assert len(notes) == 1 and "0.05 rad" in notes[0] and "80 %" in notes[0]


def test_a_config_that_sets_a_margin_keeps_it(so101, tmp_path):
    cfg = tmp_path / "mine.yaml"
    cfg.write_text("robot:\n  position_margin: 0.0\n")
    config = resolve_robot_config(so101, cfg)
    assert config.robot.position_margin == 0.0 and config.robot.velocity_scale == 0.8
    assert config.robot.assumed == ["velocity_scale"]
    robot = load_robot(config)
    note = next(n for n in robot.limit_notes if n.startswith(DEFAULTS_LINE))
    assert "position margin" not in note and "80 %" in note


@pytest.mark.parametrize("name, margin, scale", [("panda", 0.05, 0.8), ("ur5", 0.05, 0.8), ("g1", 0.05, 1.0)])
def test_the_shipped_configs_are_unchanged(name, margin, scale):
    r = resolve_robot_config(name).robot
    assert (r.position_margin, r.velocity_scale, r.assumed) == (margin, scale, [])


def test_a_narrow_prismatic_joint_keeps_a_quarter_of_its_range_and_says_m():
    # panda.urdf without pe_drake's config: the 4 cm finger joints are excited too.
    robot = load_robot(_model("panda_description/urdf/panda.urdf"))
    k = robot.joint_names.index("panda_finger_joint1")
    assert (robot.limits.q_lower[k], robot.limits.q_upper[k]) == pytest.approx((0.01, 0.03))
    j1 = robot.joint_names.index("panda_joint1")
    assert robot.limits.q_upper[j1] == pytest.approx(2.8973 - 0.05)
    note = next(n for n in robot.limit_notes if n.startswith(DEFAULTS_LINE))
    assert "m on prismatic joints" in note and "panda_finger_joint1" in note
    # 4. the assumed acceleration limit in m/s² for the fingers, rad/s² for the arm
    line = assumed_defaults(resolve_robot_config(str(robot.model_path)), robot.joint_names,
                            [j.kind for j in robot.joints])[0]
    assert re.search(r"10 rad/s² assumed for panda_joint1.*; 10 m/s² assumed for panda_finger_joint1", line)


def test_the_defaults_are_printed_once_and_recorded_in_report_json(so101_plan):
    plan, lines = so101_plan
    assert sum(DEFAULTS_LINE in line for line in lines) == 1
    margins = plan.report.to_dict()["limit_margins"]
    assert margins["position_margin"] == 0.05 and margins["velocity_scale"] == 0.8
    assert margins["assumed"] == list(SAFE_DEFAULTS)
    if plan.success:
        assert set(plan.report.ramp_margins_1khz) >= {"position", "velocity", "acceleration"}


# ---- 2. nothing outside a limit is valid ---------------------------------------------------------


def _one_joint_limits(q_upper: float):
    return types.SimpleNamespace(q_lower=np.array([-1.0]), q_upper=np.array([q_upper]),
                                 v_max=np.array([10.0]), vd_max=np.array([10.0]))


def test_a_ramp_a_hair_outside_a_position_limit_is_not_taken():
    # q = 0.5 cos(ωt): the peak sits on the join at phase 0, and the limit is 1e-8 rad below it.
    # The ramps were accepted within the solver's 1e-6 tolerance; now a phase whose ramps stay
    # inside is taken instead.
    path = FourierTrajectory(np.zeros((1, 1)), np.full((1, 1), 0.5), np.zeros(1), 2 * np.pi / 8)
    limits = _one_joint_limits(0.5 - 1e-8)
    motion, _ = choose_ramp_duration(path, limits)
    t = motion.sample_times(1000.0)
    ramps = (t <= motion.periodic_start) | (t >= motion.periodic_end)
    q, _, _ = motion.evaluate(t[ramps])
    assert q.max() <= limits.q_upper[0]


def test_the_written_motion_is_refused_for_any_excess():
    path = FourierTrajectory(np.zeros((1, 1)), np.full((1, 1), 0.5), np.zeros(1), 2 * np.pi / 8)
    motion = RampedMotion(path, 1, 0.0)
    check_written_motion(motion, _one_joint_limits(0.5), ["j"], 1000.0)  # at the limit: not outside
    with pytest.raises(NotWithinLimitsError, match=r"position \(by 1e-08"):
        check_written_motion(motion, _one_joint_limits(0.5 - 1e-8), ["j"], 1000.0)


def test_path_bounds_hold_between_samples_and_the_path_is_pulled_strictly_inside(ur5):
    problem = ExcitationProblem(ur5, dataclasses.replace(resolve_robot_config("ur5").excitation, harmonics=3))
    alpha = problem.initial_guess()
    n, lim = problem.n, ur5.limits
    t = np.linspace(0.0, problem.period, 200_001)
    q = problem.trajectory(alpha).evaluate(t)[0]
    q_hi = path_limit_bounds(problem.trajectory(alpha))[0]
    assert np.all(q_hi >= q.max(0))
    # Scale the motion so that joint 0 peaks 1e-8 rad above its limit (between 1 kHz samples).
    q0 = alpha[-n:]
    over = alpha * ((lim.q_upper[0] + 1e-8 - q0[0]) / (q[:, 0].max() - q0[0]))
    over[-n:] = q0
    fixed, scale = keep_strictly_inside(problem, over)
    assert scale < 1.0
    q_fixed = problem.trajectory(fixed).evaluate(t)[0]
    assert np.all(q_fixed <= lim.q_upper) and np.all(q_fixed >= lim.q_lower)


def test_the_so101_run_writes_nothing_outside_a_limit(so101_plan, tmp_path):
    plan, _ = so101_plan
    if not plan.success:
        pytest.skip(f"no valid motion in 3 iterations: {plan.result.message}")
    write_motion_csv(tmp_path / "trajectory.csv", plan.robot.joint_names, plan.motion, 1000.0)  # as write() does
    text = (tmp_path / "trajectory.csv").read_text().splitlines()
    header, table = text[0].split(","), np.array([[float(x) for x in row.split(",")] for row in text[1:]])
    col = {name: table[:, k] for k, name in enumerate(header)}
    lim = plan.robot.limits
    for j, name in enumerate(plan.robot.joint_names):  # the numbers as written, not as computed
        assert lim.q_lower[j] <= col[f"q.{name}"].min() and col[f"q.{name}"].max() <= lim.q_upper[j]
        assert np.abs(col[f"v.{name}"]).max() <= lim.v_max[j]
        assert np.abs(col[f"vdot.{name}"]).max() <= lim.vd_max[j]


# ---- 3. fitted capsules passed back ----------------------------------------------------------------


def _collision(plan):
    return next(c for c in plan.constraints if c.name == "collision")


def test_fitted_capsules_passed_back_keep_the_self_collision_check(so101_plan, so101, tmp_path):
    plan, _ = so101_plan
    assert plan.fitted is not None and plan.config.excitation.collision_margin == FITTED_COLLISION_MARGIN
    path = tmp_path / "fitted_capsules.yaml"
    path.write_text(plan.fitted_text)
    base = _tiny(resolve_robot_config(so101), iterations=1)
    back = dataclasses.replace(base, robot=dataclasses.replace(base.robot, capsules=str(path)))
    again = optimize_motion(back, name="so101")
    assert again.fitted is None  # nothing fitted this time
    assert again.config.excitation.collision_margin == plan.config.excitation.collision_margin
    assert _collision(again).pair_names == _collision(plan).pair_names


def test_a_fitted_file_of_an_earlier_version_gets_the_fitted_margin(so101_plan, tmp_path):
    plan, _ = so101_plan
    old = re.sub(r"# The self-collision margin.*", "", plan.fitted_text, flags=re.S)  # no collision_margin
    path = tmp_path / "old_fitted.yaml"
    path.write_text(old)
    config = plan.config
    config = dataclasses.replace(config, robot=dataclasses.replace(config.robot, capsules=str(path)),
                                 excitation=dataclasses.replace(config.excitation, collision_margin=-1.0))
    assert with_file_margin(config).excitation.collision_margin == FITTED_COLLISION_MARGIN
    hand = tmp_path / "hand.yaml"
    hand.write_text("capsules:\n  - {link: base_link, radius: 0.05, length: 0.1}\n")
    config = dataclasses.replace(config, robot=dataclasses.replace(config.robot, capsules=str(hand)))
    assert with_file_margin(config).excitation.collision_margin == -1.0  # a hand-written file: the config decides


# ---- 4. wording and units ------------------------------------------------------------------------


def test_a_long_composition_is_cut_and_negligible_terms_dropped():
    name = "hy.a - 0.01828 m.b + 1.107e-10 Ixy.c - 3.669e-06 hz.d" + "".join(f" + 0.5 m.link{k}" for k in range(60))
    short = short_composition(name)
    assert "e-10" not in short and "Ixy.c" not in short
    assert len(short) < 160 and re.search(r"… \(\d+ more\)$", short)
    assert short_composition("-0.0202 hy.g - 1 Ixy.g") == "-0.0202 hy.g - 1 Ixy.g"
    assert short_composition("1e-12 a.x + 0.5 b.y") == "0.5 b.y … (1 more)"


def test_the_summary_neither_runs_long_nor_calls_a_stopped_solver_a_failure(so101_plan):
    plan, lines = so101_plan
    assert all(len(line) < 1000 for line in lines)
    if plan.quality is not None:
        for line in plan.quality.summary_lines():
            assert not re.search(r"\de-(0[7-9]|[1-9]\d)\b", line), line
    result = plan.result
    if result.success and not result.converged:
        assert "did not converge" not in result.message
        assert "stopped at its iteration limit" in result.message
        assert plan.report.converged is False


def test_the_ignored_capsule_pairs_are_named_in_the_output_and_report_json(so101_plan):
    """stdout said only "N pair(s) touching by design ignored" (issue 21)."""
    plan, lines = so101_plan
    report = plan.report.to_dict()
    assert report["ignored_pairs"], "the SO-101's fitted capsules touch their neighbours' neighbours"
    assert report["ignored_pairs"] == [{"pair": list(p[:2]), "reason": p[2]} for p in plan.fitted.ignored_pairs]
    first = report["ignored_pairs"][0]["pair"]
    line = next(x for x in lines if "touching by design ignored" in x)
    assert f"{len(report['ignored_pairs'])} pair(s) touching by design ignored: {first[0]}/{first[1]}" in line
    assert isinstance(report["shrunk_capsules"], dict)


def test_placeholder_velocity_limits_are_named_and_a_config_silences_them(tmp_path):
    """example-robot-data's finger_edu says 1000 rad/s on every joint: the motion is then bounded
    by the acceleration limit alone, which the notes say; a config's velocity limit replaces it."""
    path = example_robot_data_dir() / "robots" / "finger_edu_description" / "robots" / "finger_edu.urdf"
    robot = load_robot(path)
    note = next(n for n in robot.limit_notes if "placeholders" in n)
    assert "finger_base_to_upper_joint 1000 rad/s" in note and "robot.velocity_limits" in note
    assert not any("placeholders" in n for n in load_robot("ur5").limit_notes)  # 3.14 rad/s: real
    config = tmp_path / "finger.yaml"
    config.write_text("robot:\n  velocity_limits: {finger_base_to_upper_joint: 5.0, finger_upper_to_middle_joint: 5.0,"
                      " finger_middle_to_lower_joint: 5.0}\n")
    tuned = load_robot(resolve_robot_config(path, config))
    assert not any("placeholders" in n for n in tuned.limit_notes)
    assert np.allclose(tuned.limits.v_max, 5.0 * tuned.config.velocity_scale)
