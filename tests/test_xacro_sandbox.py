"""A xacro file is a program: pe_drake expands one only when the user names it, and then
without builtins, file reads or environment variables unless they pass --trust-xacro
(pe_drake/multibody/xacro_sandbox.py, issue 34)."""

from __future__ import annotations

import json

import pytest

from pe_drake.exceptions import ConfigError
from pe_drake.multibody.model_files import expand_xacro

ROBOT = """<?xml version="1.0"?>
<robot xmlns:xacro="http://www.ros.org/wiki/xacro" name="{name}">
  <xacro:property name="r" value="${{0.5 * pi}}"/>
  <link name="base"><inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="l1"><inertial><mass value="${{r}}"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><axis xyz="0 0 1"/>
    <limit lower="-1" upper="1" velocity="1" effort="1"/></joint>
  {extra}
</robot>
"""


def _xacro(tmp_path, name="r", extra=""):
    path = tmp_path / "arm.urdf.xacro"
    path.write_text(ROBOT.format(name=name, extra=extra))
    return path


def _program(tmp_path, expression: str):
    """A xacro whose link name is ``expression``: xacro evaluates a property inside ``$(…)``
    first, so ``$(eval ${cmd})`` runs a call with parentheses."""
    extra = f'<xacro:property name="cmd" value="{expression}"/><link name="$(eval ${{cmd}})"/>'
    return _xacro(tmp_path, extra=extra)


def test_plain_xacro_still_expands(tmp_path):
    path = _xacro(tmp_path, name="arm", extra='<xacro:property name="cmd" value="\'a\' + str(int(2 * pi))"/>'
                  '<link name="$(eval ${cmd})"/><link name="${xacro.arg(\'x\') if False else 1}"/>')
    text = expand_xacro(path)
    assert 'name="a6"' in text and "1.5707" in text


@pytest.mark.parametrize("expression", [
    "exec(&quot;open('{marker}', 'w').write('ran')&quot;)",
    "open('{marker}', 'w').write('ran')",
    "env('HOME')",
    "str.format('{{0}}', 1)",
])
def test_dollar_eval_runs_no_code(tmp_path, expression):
    marker = tmp_path / "marker.txt"
    with pytest.raises(ConfigError, match="--trust-xacro"):
        expand_xacro(_program(tmp_path, expression.format(marker=marker)))
    assert not marker.exists()


@pytest.mark.parametrize("name", [
    "${{xacro.load_yaml('{marker}')}}",
    "${{load_yaml('{marker}')}}",
    "$(env HOME)",
    "$(optenv HOME x)",
    "${{python.type(1)}}",
    "${{'%s'.format(1)}}",
    "${{python.list._x}}",
    "${{[x for x in [1]][0].real if (x for x in [1]).gi_frame else 1}}",
])
def test_file_and_environment_reads_are_refused_unless_trusted(tmp_path, name):
    marker = tmp_path / "marker.yaml"
    marker.write_text("secret: CANARY")
    path = _xacro(tmp_path, name=name.format(marker=marker))
    with pytest.raises(ConfigError, match="--trust-xacro"):
        expand_xacro(path)


def test_trust_xacro_runs_the_file(tmp_path):
    marker = tmp_path / "marker.txt"
    path = _program(tmp_path, f"open('{marker}', 'w').write('ran')")
    expand_xacro(path, trust=True)
    assert marker.read_text() == "ran"


def test_include_outside_the_package_is_refused(tmp_path):
    secret = tmp_path / "secret"
    secret.mkdir()
    (secret / "parts.xacro").write_text('<robot xmlns:xacro="http://www.ros.org/wiki/xacro"><link name="x"/></robot>')
    model = tmp_path / "arm"
    model.mkdir()
    path = _xacro(model, extra=f'<xacro:include filename="{secret / "parts.xacro"}"/>')
    with pytest.raises(ConfigError, match="outside the xacro's folder"):
        expand_xacro(path)
    (model / "parts.xacro").write_text((secret / "parts.xacro").read_text())
    _xacro(model, extra='<xacro:include filename="parts.xacro"/>')
    assert 'name="x"' in expand_xacro(path)


def test_trajectory_naming_a_xacro_is_not_expanded(tmp_path):
    """Opening a shared trajectory.json runs nothing, whatever its "model" names."""
    from pe_drake.viewer import play_trajectory

    marker = tmp_path / "marker.txt"
    path = _program(tmp_path, f"open('{marker}', 'w').write('ran')")
    trajectory = tmp_path / "trajectory.json"
    trajectory.write_text(json.dumps({"robot": "arm", "model": str(path), "joints": ["j1"], "omega": 1.0,
                                      "harmonics": 1, "a": [[0.1]], "b": [[0.0]], "q0": [0.0], "duration": 6.28}))
    with pytest.raises(ConfigError, match="xacro file is a program"):
        play_trajectory(trajectory)
    assert not marker.exists()
    trajectory.write_text(trajectory.read_text().replace('"arm"', json.dumps(str(path)), 1))
    with pytest.raises(ConfigError, match="xacro file is a program"):
        play_trajectory(trajectory)
    assert not marker.exists()


def test_config_field_and_flag_are_checked():
    from pe_drake.config import Config, RobotConfig, validate_config

    with pytest.raises(ConfigError, match="robot.trust_xacro"):
        validate_config(Config(robot=RobotConfig(model="x.urdf", trust_xacro="yes")))


def test_an_included_pipe_is_refused_not_read(tmp_path):
    """Bounded by an alarm: on a regression the open() of the pipe blocks."""
    import os
    import signal

    def give_up(signum, frame):
        raise TimeoutError("expanding the xacro blocked on the pipe")

    os.mkfifo(tmp_path / "parts.xacro")
    previous = signal.signal(signal.SIGALRM, give_up)
    signal.alarm(20)
    try:
        with pytest.raises(ConfigError, match="named pipe"):
            expand_xacro(_xacro(tmp_path, extra='<xacro:include filename="parts.xacro"/>'))
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def test_a_property_named_like_a_removed_builtin_still_works(tmp_path):
    extra = ('<xacro:macro name="part" params="type"><link name="${type}_link"/></xacro:macro>'
             '<xacro:part type="wheel"/>')
    assert 'name="wheel_link"' in expand_xacro(_xacro(tmp_path, extra=extra))


def test_common_xacro_idioms_expand_in_the_sandbox(tmp_path):
    """What real description packages write keeps working untrusted."""
    extra = """
  <xacro:arg name="prefix" default="left_"/>
  <xacro:property name="p" value="$(arg prefix)"/>
  <xacro:property name="mode" value="a"/>
  <link name="${p}link_${int(radians(180) / pi)}"/>
  <link name="${'%s_b' % p}"/>
  <link name="${str(mode).upper()}_${' '.join(['x', 'y']).replace(' ', '')}_${len([1, 2])}"/>
  <xacro:if value="${mode == 'a'}"><link name="if_${sorted([3, 1])[0]}"/></xacro:if>
  <xacro:if value="$(eval 1 + 1 == 2)"><link name="eval_${xacro.arg('prefix')}"/></xacro:if>
  <link name="${[k for k in range(3)][-1]}_${dict(a=1)['a']}_${max(1, 2)}_${python.abs(-3)}"/>
"""
    text = expand_xacro(_xacro(tmp_path, extra=extra))
    for name in ("left_link_1", "left__b", "A_xy_2", "if_1", "eval_left_", "2_1_2_3"):
        assert f'name="{name}"' in text, name
