"""Issue 10: the controller file starts and ends at rest, arms stay above their floor, every
robot has capsules, and bad trajectory files are refused before any work."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pe_drake.cli import main
from pe_drake.excitation.trajectory_file import load_motion, load_trajectory

DATA = Path(__file__).parent / "data"


def _csv(path):
    lines = Path(path).read_text().splitlines()
    return lines[0].split(","), np.array([[float(x) for x in line.split(",")] for line in lines[1:]])


@pytest.mark.slow
def test_optimize_csv_is_ramp_in_periods_ramp_out_and_view_replays_it(tmp_path):
    cfg = tmp_path / "small.yaml"
    cfg.write_text("excitation: {harmonics: 3, cost_samples: 24, constraint_samples: 96}\nsolver: {max_iterations: 60}\n")
    out = tmp_path / "out"
    code = main(["optimize", "--robot", "panda", "--config", str(cfg), "--out", str(out), "--quiet", "--periods", "2",
                 "--no-html"])
    assert code == 0
    data = json.loads((out / "trajectory.json").read_text())
    assert data["periods"] == 2 and data["ramp_duration"] > 0
    assert data["layout"]["periodic"][1] - data["layout"]["periodic"][0] == pytest.approx(2 * data["duration"])
    header, table = _csv(out / "trajectory.csv")
    n = len(data["joints"])
    v, vd = table[:, 1 + n : 1 + 2 * n], table[:, 1 + 2 * n :]
    assert np.all(v[0] == 0) and np.all(vd[0] == 0) and np.all(v[-1] == 0) and np.all(vd[-1] == 0)
    assert table[-1, 0] == pytest.approx(data["motion_duration"], abs=1e-3)
    # simulate and view replay exactly what the CSV holds: the one function both use
    motion, _ = load_motion(out / "trajectory.json")
    q, v2, vd2 = motion.evaluate(table[:, 0])
    np.testing.assert_allclose(q, table[:, 1 : 1 + n], atol=1e-8)
    np.testing.assert_allclose(v2, v, atol=1e-8)
    report = json.loads((out / "report.json").read_text())
    assert report["motion"]["ramp_duration"] == data["ramp_duration"]
    # the whole CSV at 1 kHz stays within the limits
    from pe_drake.multibody.robot import load_robot

    lim = load_robot("panda").limits
    assert np.all(np.abs(v) <= lim.v_max + 1e-6) and np.all(np.abs(vd) <= lim.vd_max + 1e-6)
    html = tmp_path / "p.html"
    assert main(["view", str(out / "trajectory.json"), "--html", str(html)]) == 0
    assert html.stat().st_size > 1000


def test_ur5_unconstrained_optimum_goes_through_its_floor(ur5):
    """The UR5 optimum before issue 10 (no floor) sends the wrist ~0.86 m below the base plane."""
    from pe_drake.excitation.constraints.environment import EnvironmentConstraint

    trajectory, _ = load_trajectory(DATA / "ur5_no_floor_trajectory.json")
    q, v, vd = trajectory.evaluate(np.arange(0, trajectory.period, 1e-3))
    floor = EnvironmentConstraint(ur5, 0.005, floor_height=0.0)
    assert floor.margins(q, v, vd).min() < -0.5


@pytest.mark.slow
def test_ur5_optimum_stays_above_its_floor_at_1khz(tmp_path):
    out = tmp_path / "ur5"
    cfg = tmp_path / "small.yaml"
    cfg.write_text("excitation: {harmonics: 3, cost_samples: 30, constraint_samples: 120}\nsolver: {max_iterations: 80}\n")
    assert main(["optimize", "--robot", "ur5", "--config", str(cfg), "--out", str(out), "--quiet", "--no-html"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["margins_1khz"]["environment"] >= -1e-6
    from pe_drake.excitation.constraints.environment import EnvironmentConstraint
    from pe_drake.multibody.robot import load_robot

    motion, _ = load_motion(out / "trajectory.json")
    _, table = _csv(out / "trajectory.csv")
    robot = load_robot("ur5")
    floor = EnvironmentConstraint(robot, 0.005, floor_height=0.0)
    q = table[:, 1 : 1 + robot.n]
    assert floor.margins(q, q, q).min() >= -1e-6  # ramps included


def _bad_trajectory(tmp_path, **changes):
    data = json.loads((DATA / "panda_optimized.json").read_text())
    data.update(changes)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    return path


@pytest.mark.parametrize("changes, message", [
    ({"omega": 0}, "'omega' = 0"),
    ({"omega": -1.0}, "'omega' = -1.0"),
    ({"omega": "fast"}, "'omega' must be a finite number"),
    ({"omega": 1e6}, "outside"),
    ({"a": [["x"] * 5] * 7}, "'a' must hold numbers only"),
    ({"q0": [50.0] * 7}, "outside its limits"),
    ({"periods": 0}, "periods"),
    ({"ramp_duration": -2}, "ramp_duration"),
])
def test_simulate_and_view_refuse_bad_trajectory_values_before_any_work(tmp_path, capsys, changes, message):
    path = _bad_trajectory(tmp_path, **changes)
    out = tmp_path / "run.csv"
    truth = tmp_path / "truth.yaml"
    truth.write_text("{}\n")
    assert main(["simulate", "--robot", "panda", "--trajectory", str(path), "--truth", str(truth), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err and "bad.json" in err
    assert not out.exists()
    html = tmp_path / "v.html"
    assert main(["view", str(path), "--html", str(html)]) == 2
    assert message in capsys.readouterr().err
    assert not html.exists()
    assert main(["optimize", "--robot", "panda", "--prior", str(path), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_huge_amplitude_trajectory_is_refused_by_simulate(tmp_path, capsys):
    data = json.loads((DATA / "panda_optimized.json").read_text())
    path = _bad_trajectory(tmp_path, a=(np.array(data["a"]) * 100).tolist())
    truth = tmp_path / "truth.yaml"
    truth.write_text("{}\n")
    out = tmp_path / "run.csv"
    assert main(["simulate", "--robot", "panda", "--trajectory", str(path), "--truth", str(truth), "--out", str(out)]) == 2
    assert "outside its limits" in capsys.readouterr().err
    assert not out.exists()


def test_view_listens_on_localhost_by_default():
    from pe_drake.cli import build_parser

    args = build_parser().parse_args(["view", "t.json"])
    assert args.host == "localhost"


def test_ur5_ships_capsules_and_fitting_reproduces_them(tmp_path, ur5):
    from pe_drake.multibody.capsule_fitting import fit_capsule_file
    from pe_drake.multibody.capsules import load_capsule_file
    from pe_drake.multibody.registry import example_robot_data_dir

    assert len(ur5.capsules) == 7
    fitted = fit_capsule_file(example_robot_data_dir() / "robots/ur_description/urdf/ur5_robot.urdf", tmp_path / "c.yaml")
    shipped = {c.name: c for c in load_capsule_file(Path(ur5.config.capsules)).capsules}
    caps = load_capsule_file(fitted.path).capsules
    assert {c.name for c in caps} - set(shipped) == {"ee_link"}  # its <box> collision is now used too
    for c in caps:
        if c.name in shipped:
            assert c.radius == pytest.approx(shipped[c.name].radius, abs=1e-4)


def test_capsules_are_fitted_when_a_urdf_robot_has_none(tmp_path):
    """A robot folder made here: a two-link URDF with relative STL mesh paths."""
    from pe_drake.config import Config, RobotConfig
    from pe_drake.multibody.capsule_fitting import fit_capsules
    from pe_drake.multibody.meshes import TriangleMesh

    urdf = _two_link_robot(tmp_path)
    config = Config(robot=RobotConfig(model=str(urdf)))
    config, fitted = fit_capsules(config, tmp_path / "out")
    assert fitted is not None and set(fitted.links) == {"base", "link1", "link2"}
    assert config.robot.capsules == str(tmp_path / "out" / "fitted_capsules.yaml")
    from pe_drake.multibody.capsules import load_capsule_file

    caps = {c.name: c for c in load_capsule_file(config.robot.capsules).capsules}
    # a 0.1 × 0.1 × 0.4 m box (8 corner vertices): radius = half its diagonal, segment its length
    assert caps["link2"].radius == pytest.approx(0.05 * np.sqrt(2), abs=1e-3)
    assert caps["link2"].length == pytest.approx(0.4, abs=1e-3)
    assert TriangleMesh  # the mesh type the reader returns


def _box_stl(path: Path, size, offset) -> None:
    """An ASCII STL box (12 triangles)."""
    sx, sy, sz = (s / 2 for s in size)
    ox, oy, oz = offset
    corners = np.array([[x, y, z] for x in (-sx, sx) for y in (-sy, sy) for z in (-sz, sz)]) + offset
    faces = [(0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1), (2, 3, 7), (2, 7, 6),
             (0, 2, 6), (0, 6, 4), (1, 5, 7), (1, 7, 3)]
    lines = ["solid box"]
    for f in faces:
        lines.append("facet normal 0 0 0\n outer loop")
        lines += [f"  vertex {x:.6f} {y:.6f} {z:.6f}" for x, y, z in corners[list(f)]]
        lines.append(" endloop\nendfacet")
    lines.append("endsolid box")
    path.write_text("\n".join(lines) + "\n")
    assert (ox, oy, oz) is not None


def _two_link_robot(folder: Path) -> Path:
    (folder / "meshes").mkdir(parents=True, exist_ok=True)
    _box_stl(folder / "meshes" / "base.stl", (0.2, 0.2, 0.1), (0, 0, 0.05))
    _box_stl(folder / "meshes" / "link.stl", (0.1, 0.1, 0.4), (0, 0, 0.2))
    link = """
  <link name="{name}">
    <inertial><mass value="1.0"/><origin xyz="0 0 0.2"/>
      <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.002"/></inertial>
    <visual><geometry><mesh filename="meshes/{mesh}.stl"/></geometry></visual>
    <collision><geometry><mesh filename="meshes/{mesh}.stl"/></geometry></collision>
  </link>"""
    joint = """
  <joint name="{name}" type="revolute"><parent link="{parent}"/><child link="{child}"/>
    <origin xyz="0 0 {z}"/><axis xyz="0 1 0"/>
    <limit lower="-2" upper="2" velocity="2" effort="50"/></joint>"""
    text = ('<?xml version="1.0"?>\n<robot name="two_link">'
            + link.format(name="base", mesh="base") + link.format(name="link1", mesh="link")
            + link.format(name="link2", mesh="link")
            + joint.format(name="j1", parent="base", child="link1", z=0.1)
            + joint.format(name="j2", parent="link1", child="link2", z=0.4) + "\n</robot>\n")
    path = folder / "two_link.urdf"
    path.write_text(text)
    return path


def test_user_robot_with_relative_mesh_paths_and_placeholder_limits(tmp_path):
    """A robot folder made here: relative mesh paths load; zero-width URDF limits are replaced
    by the config's; a real limit can only be tightened."""
    from pe_drake.config import RobotConfig
    from pe_drake.exceptions import ConfigError, InfeasibleError
    from pe_drake.multibody.robot import load_robot

    urdf = _two_link_robot(tmp_path)
    robot = load_robot(RobotConfig(model=str(urdf)))
    assert robot.n == 2 and robot.limits.q_upper[0] == pytest.approx(2.0)
    placeholder = tmp_path / "placeholder.urdf"
    placeholder.write_text(urdf.read_text().replace('lower="-2" upper="2" velocity="2"', 'lower="0" upper="0" velocity="0"'))
    with pytest.raises(ConfigError, match=r"no velocity limit: set robot.velocity_limits\['j1'\]"):
        load_robot(RobotConfig(model=str(placeholder)))
    with pytest.raises(InfeasibleError, match=r"give a real range in robot.position_limits\['j1'\]"):
        load_robot(RobotConfig(model=str(placeholder), velocity_limits={"j1": 4.0, "j2": 4.0}))
    robot = load_robot(RobotConfig(model=str(placeholder), position_limits={"j1": [-3, 3], "j2": [-1, 1]},
                                   velocity_limits={"j1": 4.0, "j2": 4.0}))
    assert robot.limits.q_lower[0] == pytest.approx(-3) and robot.limits.v_max[1] == pytest.approx(4.0)
    with pytest.raises(ConfigError, match=r"wider than the limits \[-2, 2\] in two_link.urdf"):
        load_robot(RobotConfig(model=str(urdf), position_limits={"j1": [-3, 3]}))
    with pytest.raises(ConfigError, match="above the limit 2 in two_link.urdf"):
        load_robot(RobotConfig(model=str(urdf), velocity_limits={"j1": 3.0}))
    tight = load_robot(RobotConfig(model=str(urdf), position_limits={"j1": [-1, 1]}, velocity_limits={"j1": 1.0}))
    assert tight.limits.q_upper[0] == pytest.approx(1.0) and tight.limits.v_max[0] == pytest.approx(1.0)


@pytest.mark.parametrize("kind, message", [
    ("floating", "joint 'j1' has type 'floating'; pe_drake supports revolute"),
    ("ball", "joint 'j1' has type 'ball'; pe_drake supports revolute"),
])
def test_floating_and_ball_joints_are_named(tmp_path, capsys, kind, message):
    urdf = _two_link_robot(tmp_path)
    bad = tmp_path / f"{kind}.urdf"
    bad.write_text(urdf.read_text().replace('<joint name="j1" type="revolute">', f'<joint name="j1" type="{kind}">'))
    assert main(["optimize", "--robot", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_joint_types_in_comments_are_ignored():
    from pe_drake.multibody.urdf_checks import check_joint_types

    check_joint_types('<robot><!-- <joint name="f" type="floating">\n --><joint name="j" type="revolute"/></robot>', "r.urdf")


def test_fitted_capsules_of_a_urdf_path_switch_self_collision_on_and_skip_pairs_touching_by_design(tmp_path):
    """The UR10 through its URDF path came within 5-7 mm mesh to mesh: it now gets capsules."""
    from pe_drake.multibody.capsule_fitting import FITTED_COLLISION_MARGIN, fit_capsules
    from pe_drake.multibody.registry import example_robot_data_dir, resolve_robot_config

    config = resolve_robot_config(str(example_robot_data_dir() / "robots/ur_description/urdf/ur10_robot.urdf"))
    assert config.excitation.collision_margin < 0
    config, fitted = fit_capsules(config, tmp_path)
    assert config.excitation.collision_margin == FITTED_COLLISION_MARGIN
    assert len(fitted.links) == 8 and fitted.sources["ee_link"] == "primitive"  # 7 meshes + the <box> ee_link
    pairs = {frozenset(p[:2]) for p in fitted.ignored_pairs}
    assert frozenset(("base_link", "upper_arm_link")) in pairs
    assert "ignored_pairs:" in fitted.path.read_text()
