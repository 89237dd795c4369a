# ruff: noqa: E501 (URDF text on one line per link)
"""Capsules from primitive collision shapes, DAE meshes and SDF links (issue 21)."""

import numpy as np
import pytest

from pe_drake.multibody.capsule_fitting import CapsuleFittingError, fit_capsule_file
from pe_drake.multibody.capsules import load_capsule_file
from pe_drake.multibody.registry import example_robot_data_dir

_URDF = """<robot name="prim">
  <link name="base"><collision><origin xyz="0 0 0.05"/><geometry><cylinder radius="0.06" length="0.1"/></geometry></collision></link>
  <link name="arm"><inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><origin xyz="0 0 0.2" rpy="0 0 0"/><geometry><box size="0.04 0.06 0.4"/></geometry></collision></link>
  <link name="tip"><inertial><mass value="0.5"/><inertia ixx="0.001" iyy="0.001" izz="0.001" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><origin xyz="0.1 0 0"/><geometry><sphere radius="0.03"/></geometry></collision>
    <collision><origin xyz="0 0 0" rpy="0 1.5707963267948966 0"/><geometry><cylinder radius="0.02" length="0.2"/></geometry></collision></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="arm"/><origin xyz="0 0 0.1"/><axis xyz="0 0 1"/><limit lower="-2" upper="2" effort="10" velocity="2"/></joint>
  <joint name="j2" type="revolute"><parent link="arm"/><child link="tip"/><origin xyz="0 0 0.4"/><axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="10" velocity="2"/></joint>
</robot>
"""


def _ends(c):
    from pe_drake.multibody.link_geometry import rotation_rpy

    z = rotation_rpy(c.rpy)[:, 2]
    return np.asarray(c.xyz) - 0.5 * c.length * z, np.asarray(c.xyz) + 0.5 * c.length * z


def test_primitive_only_robot_gets_enclosing_capsules(tmp_path):
    """Fails on the old code: it read only STL/OBJ meshes and refused a primitive-only robot."""
    urdf = tmp_path / "prim.urdf"
    urdf.write_text(_URDF)
    fitted = fit_capsule_file(urdf, tmp_path / "c.yaml")
    assert fitted.unchecked == () and set(fitted.links) == {"base", "arm", "tip"}
    assert set(fitted.sources.values()) == {"primitive"}
    caps = {c.name: c for c in load_capsule_file(fitted.path).capsules}
    # cylinder: same radius, axis and length
    assert caps["base"].radius == pytest.approx(0.06) and caps["base"].length == pytest.approx(0.1)
    p0, p1 = _ends(caps["base"])
    np.testing.assert_allclose(sorted([p0[2], p1[2]]), [0.0, 0.1], atol=1e-4)
    # box: along its longest edge, radius half the cross-section diagonal, corners inside
    assert caps["arm"].radius == pytest.approx(0.5 * np.hypot(0.04, 0.06), abs=1e-4)
    assert caps["arm"].length == pytest.approx(0.4, abs=1e-4)
    # two shapes on 'tip': one capsule each (a sphere is a ~zero-length capsule)
    assert caps["tip"].radius == pytest.approx(0.03) and caps["tip"].length <= 1e-3
    assert caps["tip_1"].radius == pytest.approx(0.02) and caps["tip_1"].length == pytest.approx(0.2)
    p0, p1 = _ends(caps["tip_1"])
    np.testing.assert_allclose(np.abs(p1 - p0), [0.2, 0, 0], atol=1e-4)


def test_sdf_primitives_are_read(tmp_path):
    sdf = tmp_path / "m.sdf"
    sdf.write_text(
        '<sdf version="1.7"><model name="m"><link name="a"><collision name="c"><pose>0 0 0.1 0 0 0</pose>'
        "<geometry><capsule><radius>0.05</radius><length>0.3</length></capsule></geometry></collision></link>"
        "</model></sdf>"
    )
    caps = load_capsule_file(fit_capsule_file(sdf, tmp_path / "c.yaml").path).capsules
    assert [c.link for c in caps] == ["a"] and caps[0].radius == pytest.approx(0.05)
    assert caps[0].xyz == pytest.approx([0, 0, 0.1], abs=1e-4)


@pytest.mark.parametrize("fmt, geometry", [
    ("urdf", '<cylinder length="0.3"/>'),
    ("sdf", "<sphere></sphere>"),
])
def test_a_primitive_without_its_size_is_a_config_error_naming_it(tmp_path, fmt, geometry):
    """A <cylinder> without radius was a float(None) TypeError traceback out of `optimize`."""
    from pe_drake.exceptions import ConfigError
    from pe_drake.multibody.link_geometry import read_link_shapes

    path = tmp_path / f"m.{fmt}"
    if fmt == "urdf":
        path.write_text(f'<robot name="m"><link name="a"><collision><geometry>{geometry}</geometry></collision></link></robot>')
    else:
        path.write_text(f'<sdf version="1.7"><model name="m"><link name="a"><collision name="c"><geometry>{geometry}'
                        "</geometry></collision></link></model></sdf>")
    with pytest.raises(ConfigError, match=r"link 'a': bad <collision> geometry: <(cylinder|sphere)> has no radius"):
        read_link_shapes(path)


def test_dae_only_robot_gets_capsules_and_unreadable_meshes_are_unchecked(tmp_path):
    """Fails on the old code: DAE meshes were not read and the robot got no capsule at all."""
    dae = example_robot_data_dir() / "robots/kinova_description/meshes/forearm.dae"
    if not dae.is_file():
        pytest.skip("example-robot-data's Kinova meshes are absent")
    (tmp_path / "broken.dae").write_text("<COLLADA><not closed")
    urdf = tmp_path / "dae.urdf"
    urdf.write_text(
        f'<robot name="d"><link name="fore"><collision><geometry><mesh filename="{dae.as_uri()}"/></geometry>'
        '</collision></link><link name="bad"><collision><geometry><mesh filename="broken.dae"/></geometry>'
        '</collision><collision><geometry><mesh filename="missing.dae"/></geometry></collision></link>'
        '<joint name="j" type="revolute"><parent link="fore"/><child link="bad"/><axis xyz="0 0 1"/>'
        '<limit lower="-1" upper="1" effort="1" velocity="1"/></joint></robot>'
    )
    fitted = fit_capsule_file(urdf, tmp_path / "c.yaml")
    assert fitted.links == ("fore",) and fitted.sources["fore"] == "mesh"
    cap = load_capsule_file(fitted.path).capsules[0]
    assert 0.03 < cap.radius < 0.06 and 0.1 < cap.length < 0.3  # the 0.08 × 0.25 m forearm shell
    assert len(fitted.unchecked) == 1 and fitted.unchecked[0].startswith("link bad: ")
    assert "broken.dae" in fitted.unchecked[0] and "missing.dae" in fitted.unchecked[0]
    assert "1 part(s) NOT checked" in fitted.summary()


def test_nothing_fittable_raises_a_short_error_with_the_unchecked_list(tmp_path):
    urdf = tmp_path / "none.urdf"
    links = "".join(
        f'<link name="l{k}"><collision><geometry><mesh filename="m{k}.dae"/></geometry></collision></link>' for k in range(40)
    )
    urdf.write_text(f'<robot name="n">{links}</robot>')
    with pytest.raises(CapsuleFittingError) as info:
        fit_capsule_file(urdf, tmp_path / "c.yaml")
    assert len(info.value.unchecked) == 40 and len(str(info.value)) < 400
    assert not (tmp_path / "c.yaml").exists()


def test_z1_primitives_give_capsules(tmp_path):
    """The Z1's collision shapes are cylinders and boxes: every link gets capsules from them."""
    urdf = example_robot_data_dir() / "robots/z1_description/urdf/z1.urdf"
    if not urdf.is_file():
        pytest.skip("example-robot-data's Z1 is absent")
    fitted = fit_capsule_file(urdf, tmp_path / "c.yaml")
    assert fitted.unchecked == ()
    assert sum(v == "primitive" for v in fitted.sources.values()) >= 5
    assert len(load_capsule_file(fitted.path).capsules) > len(fitted.links)  # several shapes per link
