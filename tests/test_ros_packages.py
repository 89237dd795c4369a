"""A robot laid out as ROS packages (issue 21, "Loading"): package:// URIs found above the
model, through ROS_PACKAGE_PATH, AMENT_PREFIX_PATH and robot.packages; absolute mesh paths;
.urdf.xacro files; Drake's refusals of plain ROS robots."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from pe_drake.exceptions import ConfigError
from pe_drake.multibody.meshes import read_stl
from pe_drake.multibody.packages import clear_cache, find_package, resolve_package_uri
from pe_drake.multibody.registry import example_robot_data_dir
from pe_drake.multibody.robot import load_robot

PKG = "my_arm_description"
UR5 = "robots/ur_description/urdf/ur5_robot.urdf"
_MESH = re.compile(r'filename="package://example-robot-data/robots/ur_description/meshes/ur5/(?:collision|visual)/(\w+)\.(?:stl|dae)"')


@pytest.fixture(autouse=True)
def _no_ros_environment(monkeypatch, tmp_path):
    """No ROS workspace of the machine leaks in; converted meshes go to tmp_path."""
    monkeypatch.delenv("ROS_PACKAGE_PATH", raising=False)
    monkeypatch.delenv("AMENT_PREFIX_PATH", raising=False)
    monkeypatch.setenv("PE_DRAKE_MESH_CACHE", str(tmp_path / "cache"))
    clear_cache()


def write_binary_stl(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """A binary STL written with numpy (80-byte header, count, 50 bytes per facet)."""
    dtype = np.dtype([("normal", "<f4", (3,)), ("vertices", "<f4", (3, 3)), ("attribute", "<u2")])
    facets = np.zeros(len(faces), dtype)
    facets["vertices"] = vertices[faces]
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("wb") as out:
        out.write(b"pe_drake test mesh".ljust(80, b" "))
        out.write(np.uint32(len(faces)).tobytes())
        out.write(facets.tobytes())


def ur5_text(filename: str) -> str:
    """example-robot-data's UR5 with each mesh named by ``filename.format(name=<mesh>)``."""
    text = (example_robot_data_dir() / UR5).read_text()
    return _MESH.sub(lambda m: f'filename="{filename.format(name=m.group(1))}"', text)


def write_package(folder: Path, name: str = PKG, urdf: bool = True) -> Path:
    """A ROS description package: package.xml, meshes/*.stl (UR5's collision meshes, decimated
    vertices kept), and urdf/my_arm.urdf using package://<name>/meshes/<mesh>.stl."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "package.xml").write_text(
        f'<?xml version="1.0"?>\n<package format="3">\n  <name>{name}</name>\n  <version>0.1.0</version>\n'
        "  <description>test arm</description>\n</package>\n"
    )
    source = example_robot_data_dir() / "robots/ur_description/meshes/ur5/collision"
    for stl in source.glob("*.stl"):
        mesh = read_stl(stl)
        write_binary_stl(folder / "meshes" / stl.name, mesh.vertices, mesh.faces)
    path = folder / "urdf" / "my_arm.urdf"
    if urdf:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(ur5_text(f"package://{name}/meshes/{{name}}.stl"))
    return path


def outside_urdf(tmp_path: Path) -> Path:
    """The package's URDF copied outside the package (a generated or downloaded file)."""
    path = tmp_path / "elsewhere" / "my_arm.urdf"
    path.parent.mkdir(parents=True)
    path.write_text(ur5_text(f"package://{PKG}/meshes/{{name}}.stl"))
    return path


def check_arm(robot) -> None:
    ur5 = load_robot("ur5")
    assert robot.n == 6 and robot.joint_names == ur5.joint_names
    np.testing.assert_allclose(robot.phi_model, ur5.phi_model)


def test_package_found_above_the_model(tmp_path):
    urdf = write_package(tmp_path / "ws" / "src" / PKG)
    check_arm(load_robot(str(urdf)))


def test_package_found_by_its_manifest_name(tmp_path):
    """The folder is not named like the package (a git checkout): package.xml's <name> counts."""
    urdf = write_package(tmp_path / "ws" / "src" / "arm-repo")
    check_arm(load_robot(str(urdf)))


def test_unknown_package_says_where_it_looked(tmp_path):
    write_package(tmp_path / "ws" / "src" / PKG)
    with pytest.raises(ConfigError, match=r"ROS_PACKAGE_PATH.*robot\.packages"):
        load_robot(str(outside_urdf(tmp_path)))


def test_ros_package_path(tmp_path, monkeypatch):
    write_package(tmp_path / "ws" / "src" / "group" / PKG)
    urdf = outside_urdf(tmp_path)
    monkeypatch.setenv("ROS_PACKAGE_PATH", f"/nonexistent:{tmp_path / 'ws' / 'src'}")
    check_arm(load_robot(str(urdf)))


def test_ament_prefix_path(tmp_path, monkeypatch):
    """A colcon install: <prefix>/share/<package>."""
    write_package(tmp_path / "install" / PKG / "share" / PKG, urdf=False)
    urdf = outside_urdf(tmp_path)
    monkeypatch.setenv("AMENT_PREFIX_PATH", f"{tmp_path / 'install' / PKG}:/opt/ros/none")
    check_arm(load_robot(str(urdf)))


def test_config_packages_map_and_capsule_fitting(tmp_path):
    from pe_drake.config import load_config
    from pe_drake.multibody.capsule_fitting import fit_capsules

    write_package(tmp_path / "ws" / "src" / PKG)
    urdf = outside_urdf(tmp_path)
    cfg_file = tmp_path / "elsewhere" / "arm.yaml"
    cfg_file.write_text(f"robot:\n  model: my_arm.urdf\n  packages: {{{PKG}: ../ws/src/{PKG}}}\n")
    config = load_config(cfg_file)
    assert config.robot.packages == {PKG: str((tmp_path / "ws" / "src" / PKG).resolve())}
    check_arm(load_robot(config))
    config, fitted = fit_capsules(config, tmp_path / "fit")
    assert fitted is not None and len(fitted.links) >= 6, urdf


def test_config_packages_folder_must_exist(tmp_path):
    from pe_drake.config import load_config

    cfg_file = tmp_path / "arm.yaml"
    cfg_file.write_text(f"robot:\n  model: arm.urdf\n  packages: {{{PKG}: missing}}\n")
    with pytest.raises(ConfigError, match=r"robot.packages\['my_arm_description'\].*does not exist"):
        load_config(cfg_file)


def test_absolute_mesh_paths(tmp_path):
    write_package(tmp_path / "pkg", urdf=False)
    urdf = tmp_path / "abs.urdf"
    urdf.write_text(ur5_text(str(tmp_path / "pkg" / "meshes") + "/{name}.stl"))
    check_arm(load_robot(str(urdf)))


XACRO = """<?xml version="1.0"?>
<robot xmlns:xacro="http://www.ros.org/wiki/xacro" name="my_arm">
  <xacro:property name="pkg" value="$(find my_arm_description)"/>
  <xacro:macro name="mesh" params="file">
    <mesh filename="${pkg}/meshes/${file}.stl"/>
  </xacro:macro>
BODY
</robot>
"""


def xacro_text() -> str:
    """UR5 as a xacro file: meshes through $(find) and a macro."""
    text = ur5_text("XMESH:{name}")
    body = text[text.index(">", text.index("<robot")) + 1 : text.rindex("</robot>")]
    body = re.sub(r'<mesh filename="XMESH:(\w+)"\s*/>', r'<xacro:mesh file="\1"/>', body)
    return XACRO.replace("BODY", body)


def test_xacro_with_find_above_and_through_ament(tmp_path, monkeypatch):
    pkg = tmp_path / "ws" / "src" / PKG
    write_package(pkg, urdf=False)
    (pkg / "urdf" / "my_arm.urdf.xacro").parent.mkdir(parents=True, exist_ok=True)
    (pkg / "urdf" / "my_arm.urdf.xacro").write_text(xacro_text())
    robot = load_robot(str(pkg / "urdf" / "my_arm.urdf.xacro"))
    assert robot.name == "my_arm"
    check_arm(robot)
    # the same file outside the package: $(find) through AMENT_PREFIX_PATH
    install = tmp_path / "install" / PKG / "share" / PKG
    write_package(install, urdf=False)
    outside = tmp_path / "other" / "my_arm.urdf.xacro"
    outside.parent.mkdir()
    outside.write_text(xacro_text())
    with pytest.raises(ConfigError, match="package 'my_arm_description'"):
        load_robot(str(outside))
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(tmp_path / "install" / PKG))
    assert find_package(PKG, outside) == install.resolve()
    check_arm(load_robot(str(outside)))


def test_xacro_robot_runs_optimize(tmp_path):
    """The whole first run of a new user: a xacro package, no config, capsules fitted."""
    from pe_drake.cli import main

    pkg = tmp_path / "ws" / "src" / PKG
    write_package(pkg, urdf=False)
    (pkg / "urdf").mkdir()
    (pkg / "urdf" / "my_arm.urdf.xacro").write_text(xacro_text())
    out = tmp_path / "out"
    code = main(
        ["optimize", "--robot", str(pkg / "urdf" / "my_arm.urdf.xacro"), "--out", str(out),
         "--max-iterations", "20", "--quiet", "--csv-rate", "20"]
    )
    # 20 iterations need not converge; the run completes (after 5 this arm was still far from
    # the best point it had evaluated, which writes no trajectory: issue 38)
    assert code in (0, 1), code
    assert (out / "trajectory.json").is_file() and (out / "fitted_capsules.yaml").is_file()
    assert json.loads((out / "trajectory.json").read_text())["capsules"] == "fitted_capsules.yaml"  # view draws them


def test_repeated_material_definitions_kinova():
    """example-robot-data's JACO2 defines 'carbon_fiber' in every link: Drake refuses repeats."""
    robot = load_robot(str(example_robot_data_dir() / "robots/kinova_description/robots/kinova.urdf"))
    assert robot.n == 6
    assert any("carbon_fiber" in note for note in robot.notes)


def test_movable_world_joint_is_refused(tmp_path):
    """A root on a prismatic joint (a rail) from the world: exit 2 with what is supported."""
    from pe_drake.cli import main

    text = ur5_text("package://example-robot-data/robots/ur_description/meshes/ur5/collision/{name}.stl")
    text = re.sub(
        r'<joint name="world_joint" type="fixed">',
        '<joint name="world_joint" type="prismatic"><axis xyz="1 0 0"/>'
        '<limit lower="0" upper="1" effort="100" velocity="1"/>',
        text,
    )
    urdf = tmp_path / "rail.urdf"
    urdf.write_text(text)
    with pytest.raises(ConfigError, match=r"world_joint.*prismatic.*fixed-base"):
        load_robot(str(urdf))
    assert main(["optimize", "--robot", str(urdf), "--out", str(tmp_path / "o"), "--quiet"]) == 2


def test_talos_identified_model_reloads(tmp_path):
    """TALOS's fixed gripper joints carry <mimic> tags: Drake refused the exported model.urdf."""
    from pe_drake.multibody.robot_model import RobotModel

    robot = load_robot(str(example_robot_data_dir() / "robots/talos_data/robots/talos_reduced.urdf"))
    assert any("mimic" in note for note in robot.notes)
    phi = robot.phi_model * 1.1
    path = tmp_path / "model.urdf"
    RobotModel(robot.joint_names, robot.body_names, phi).write_urdf(path, robot)
    again = load_robot(str(path))
    np.testing.assert_allclose(again.phi_model, phi, rtol=1e-9, atol=1e-12)


def test_kinova_identified_model_reloads(tmp_path):
    from pe_drake.multibody.robot_model import RobotModel

    robot = load_robot(str(example_robot_data_dir() / "robots/kinova_description/robots/kinova.urdf"))
    path = tmp_path / "model.urdf"
    RobotModel(robot.joint_names, robot.body_names, robot.phi_model).write_urdf(path, robot)
    np.testing.assert_allclose(load_robot(str(path)).phi_model, robot.phi_model, rtol=1e-9, atol=1e-12)


def test_nominal_posture_found_for_a_user_ur_arm(tmp_path):
    """UR5 as a user URDF, no config: its mid-range (zero) posture has the wrist below the
    base plane; a posture that clears the floor and the capsules is chosen and named."""
    from pe_drake.config import Config, RobotConfig
    from pe_drake.excitation.constraints import constraints_from_config
    from pe_drake.excitation.nominal import choose_nominal_posture
    from pe_drake.multibody.capsule_fitting import fit_capsules

    urdf = write_package(tmp_path / "ws" / "src" / PKG)
    config = Config(robot=RobotConfig(model=str(urdf)))
    config, _ = fit_capsules(config, tmp_path / "fit")
    robot = load_robot(config)
    from pe_drake.exceptions import InfeasibleError

    with pytest.raises(InfeasibleError, match="floor"):
        constraints_from_config(robot, config.excitation, config.environment)
    note = choose_nominal_posture(robot, config.excitation, config.environment)
    assert note is not None and "joint" in note
    constraints = constraints_from_config(robot, config.excitation, config.environment)
    assert {c.name for c in constraints} >= {"environment"}
    assert choose_nominal_posture(robot, config.excitation, config.environment) is None  # config now has one


LOOP_SDF = """<?xml version="1.0"?>
<sdf version="1.7">
<model name="loop">
  <link name="base"><inertial><mass>1</mass></inertial></link>
  <link name="a"><pose>0 0 1 0 0 0</pose><inertial><mass>1</mass></inertial></link>
  <link name="b"><pose>1 0 1 0 0 0</pose><inertial><mass>1</mass></inertial></link>
  JOINTS
</model>
</sdf>
"""
_JOINT = ('<joint name="{}" type="revolute"><parent>{}</parent><child>{}</child><axis><xyz>0 1 0</xyz>'
          "<limit><lower>-1</lower><upper>1</upper><velocity>1</velocity></limit></axis></joint>")


def test_closed_loop_is_refused(tmp_path, capsys):
    """A four-bar-like SDF: Drake's loop error becomes exit 2 saying what is supported."""
    from pe_drake.cli import main

    joints = "".join(_JOINT.format(*j) for j in (("j1", "base", "a"), ("j2", "a", "b"), ("j3", "base", "b")))
    sdf = tmp_path / "loop.sdf"
    sdf.write_text(LOOP_SDF.replace("JOINTS", joints))
    with pytest.raises(ConfigError, match=r"closed kinematic loop.*kinematic trees"):
        load_robot(str(sdf))
    assert main(["optimize", "--robot", str(sdf), "--out", str(tmp_path / "o"), "--quiet"]) == 2


def test_package_uri_with_three_slashes_resolves():
    """TALOS's URDFs write ``package:///example-robot-data/...``; ROS and Drake read it as
    ``package://example-robot-data/...``, so every mesh of it must be found."""
    model = example_robot_data_dir() / "robots" / "talos_data" / "robots" / "talos_full_v2.urdf"
    if not model.is_file():
        pytest.skip("example-robot-data without TALOS")
    name = re.search(r'filename="(package:///[^"]+)"', model.read_text()).group(1)
    found = resolve_package_uri(name, model)
    assert found is not None and found.is_file()
    assert found == resolve_package_uri(name.replace(":///", "://"), model)


def test_materials_used_before_their_definition_or_defined_nowhere():
    """Drake refuses a material used before its (in-link) definition and one defined nowhere;
    global definitions (children of <robot>) may come anywhere."""
    from pe_drake.multibody.model_files import single_material_definitions

    text = ('<robot name="r"><link name="a"><visual><material name="G"/></visual></link>'
            '<link name="b"><visual><material name="G"><color rgba="1 0 0 1"/></material></visual></link>'
            '<link name="c"><visual><material name="X"/><material name="W"/></visual></link>'
            '<material name="W"><color rgba="1 1 1 1"/></material></robot>')
    out, notes = single_material_definitions(text)
    assert out.index('<color rgba="1 0 0 1"/>') < out.index('<link name="b">')  # G's definition at its first use
    assert '<link name="b"><visual><material name="G"/>' in out
    assert 'name="X"' not in out and '<material name="W"/>' in out and '<color rgba="1 1 1 1"/>' in out
    assert any("moved to their first use" in n and "'G'" in n for n in notes)
    assert any("defined nowhere" in n and "'X'" in n for n in notes)


@pytest.mark.parametrize("name", ["talos_full_v2.urdf", "talos_reduced_corrected.urdf"])
def test_talos_models_drake_refused_load(name):
    """TALOS full (materials used before their definition, package:/// URIs) and reduced_corrected
    (a material defined nowhere) were refused by Drake."""
    robot = load_robot(str(example_robot_data_dir() / "robots" / "talos_data" / "robots" / name))
    assert robot.n == 14


@pytest.mark.parametrize("manifest", [True, False])
def test_diagnose_writes_its_model_for_a_robot_in_a_package_folder(tmp_path, manifest):
    """Issue 36: the augmented URDF's self-check re-read it from out/.staging-*, where the
    package (found above the input model, by its package.xml or its folder name) was unknown,
    so diagnose wrote nothing."""
    from pe_drake.cli import main
    from pe_drake.identification.measurements import Measurement, write_measurement_csv

    path = write_package(tmp_path / PKG)
    if not manifest:
        (tmp_path / PKG / "package.xml").unlink()
    robot = load_robot(str(path))
    t = np.arange(0.0, 12.0, 0.005)
    rng = np.random.default_rng(0)
    a, phase = rng.uniform(0.3, 0.8, (3, robot.n)), rng.uniform(0, 2 * np.pi, (3, robot.n))
    w = 2 * np.pi / 6 * np.arange(1, 4)[:, None, None]  # three harmonics of a 6 s period [rad/s]
    arg = w * t[None, :, None] + phase[:, None, :]
    q = np.sum(a[:, None] / w * np.sin(arg), axis=0)
    v = np.sum(a[:, None] * np.cos(arg), axis=0)
    vd = np.sum(-a[:, None] * w * np.sin(arg), axis=0)
    tau = robot.inverse_dynamics(q, v, vd) + rng.normal(0, 0.02, q.shape)
    write_measurement_csv(tmp_path / "run.csv", Measurement(t, q, tau, v, vd, robot.joint_names))
    out = tmp_path / "out"
    assert main(["diagnose", "--robot", str(path), "--data", str(tmp_path / "run.csv"), "--out", str(out)]) == 0
    check = json.loads((out / "augmented_model.json").read_text())["urdf_check_max_abs_torque"]
    assert (out / "augmented_model.urdf").is_file() and check < 1e-6
    assert not list(out.glob(".staging-*"))


def test_a_transmission_of_a_joint_the_file_does_not_define_is_ignored_with_a_note():
    """example-robot-data's talos_left_arm.urdf is cut from the full TALOS with the transmission
    of arm_left_1_joint kept: Drake refused the whole file."""
    robot = load_robot(str(example_robot_data_dir() / "robots/talos_data/robots/talos_left_arm.urdf"))
    assert any("transmission" in note and "arm_left_1_joint" in note for note in robot.notes)
    assert "arm_left_2_joint" in robot.joint_names and "arm_left_1_joint" not in robot.joint_names


def test_the_model_urdf_of_a_file_with_a_dangling_transmission_reloads(tmp_path):
    """diagnose's self-check refused its own augmented_model.urdf of talos_left_arm.urdf."""
    from pe_drake.multibody.robot_model import RobotModel

    robot = load_robot(str(example_robot_data_dir() / "robots/talos_data/robots/talos_left_arm.urdf"))
    path = tmp_path / "model.urdf"
    RobotModel(robot.joint_names, robot.body_names, robot.phi_model * 1.1).write_urdf(path, robot)
    assert "<transmission" in path.read_text()  # the others are kept for ROS tools
    np.testing.assert_allclose(load_robot(str(path)).phi_model, robot.phi_model * 1.1, rtol=1e-9, atol=1e-12)
