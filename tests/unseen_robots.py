# ruff: noqa: E501 (URDF/SDF text on one line per link)
"""Small robots of the kinds issue 37 tried (a SCARA with a vertical quill, an SDF with a prismatic
joint, a model without inertials, an arm whose capsule file carries its margin), written as text so
that tests and ``python -m pe_drake.bench robots`` can build them without downloads."""

from __future__ import annotations

from pathlib import Path

_I = '<inertial><origin xyz="{c}"/><mass value="{m}"/><inertia ixx="{i}" iyy="{i}" izz="{i}" ixy="0" ixz="0" iyz="0"/></inertial>'


def _inertial(m: float, c: str = "0 0 0", i: float = 0.01) -> str:
    return _I.format(m=m, c=c, i=i)


_COLLISION = '<collision><origin xyz="0 0 {z}"/><geometry><cylinder radius="{r}" length="{L}"/></geometry></collision>'


def folding_arm(folder: Path, margin: float = 0.05, collision: bool = False) -> tuple[Path, Path]:
    """A 3-joint arm about x whose hand can fold back onto its base post, and a capsule file that
    records ``collision_margin`` (as a fitted file does). ``collision``: the URDF has cylinders
    as collision geometry (capsules can be fitted to them). Returns (urdf, capsule file)."""
    shapes = dict(base=(0.325, 0.06, 0.35), l2=(0.15, 0.04, 0.2), hand=(0.08, 0.04, 0.1)) if collision else {}
    joint = ('<joint name="j{k}" type="revolute"><parent link="{p}"/><child link="{c}"/><origin xyz="0 0 {z}"/>'
             '<axis xyz="1 0 0"/><limit lower="-2.6" upper="2.6" effort="80" velocity="2"/></joint>')
    inertials = dict(base=(5, "0 0 0.2"), l1=(1.5, "0 0 0.15"), l2=(1.5, "0 0 0.15"), hand=(0.5, "0 0 0.05"))
    links = ['<link name="world"/>'] + [
        f'<link name="{name}">{_inertial(*inertial)}'
        + (_COLLISION.format(z=shapes[name][0], r=shapes[name][1], L=shapes[name][2]) if name in shapes else "") + "</link>"
        for name, inertial in inertials.items()]
    joints = ['<joint name="w" type="fixed"><parent link="world"/><child link="base"/></joint>',
              joint.format(k=1, p="base", c="l1", z=0.6), joint.format(k=2, p="l1", c="l2", z=0.3),
              joint.format(k=3, p="l2", c="hand", z=0.3)]
    urdf = Path(folder) / "folding.urdf"
    urdf.write_text('<robot name="folding">' + "".join(links + joints) + "</robot>")
    capsules = Path(folder) / "folding_capsules.yaml"
    capsules.write_text(
        "capsules:\n"
        "  - {name: post, link: base, radius: 0.06, length: 0.35, xyz: [0, 0, 0.325], rpy: [0, 0, 0]}\n"
        "  - {name: l2, link: l2, radius: 0.04, length: 0.2, xyz: [0, 0, 0.15], rpy: [0, 0, 0]}\n"
        "  - {name: hand, link: hand, radius: 0.04, length: 0.1, xyz: [0, 0, 0.08], rpy: [0, 0, 0]}\n"
        f"collision_margin: {margin}\n")
    return urdf, capsules


def scara(folder: Path, fmt: str = "urdf") -> Path:
    """A SCARA: two vertical revolute axes, a vertical prismatic quill (it carries its own weight),
    a vertical wrist and a tool link; every axis parallel to gravity. ``fmt``: "urdf" or "sdf"."""
    bodies = [("base", 8.0, "0 0 0.2", 0.1), ("upper", 3.0, "0.2 0 0", 0.02), ("fore", 2.0, "0.15 0 0", 0.01),
              ("quill", 1.0, "0 0 -0.1", 0.005), ("tool", 0.3, "0 0 -0.02", 0.001)]
    joints = [("shoulder", "revolute", "base", "upper", "0 0 0.5", -2.5, 2.5),
              ("elbow", "revolute", "upper", "fore", "0.35 0 0", -2.5, 2.5),
              ("lift", "prismatic", "fore", "quill", "0.3 0 0", -0.15, 0.0),
              ("wrist", "revolute", "quill", "tool", "0 0 -0.2", -3.0, 3.0)]
    if fmt == "sdf":
        return _scara_sdf(Path(folder), bodies, joints)
    links = ['<link name="world"/>'] + [f'<link name="{n}">{_inertial(m, c, i)}</link>' for n, m, c, i in bodies]
    js = ['<joint name="fix" type="fixed"><parent link="world"/><child link="base"/></joint>'] + [
        f'<joint name="{n}" type="{t}"><parent link="{p}"/><child link="{c}"/><origin xyz="{o}"/><axis xyz="0 0 1"/>'
        f'<limit lower="{lo}" upper="{hi}" effort="{60 if t == "prismatic" else 40}" velocity="{0.5 if t == "prismatic" else 2}"/></joint>'
        for n, t, p, c, o, lo, hi in joints]
    path = Path(folder) / "scara.urdf"
    path.write_text('<robot name="scara">' + "".join(links + js) + "</robot>")
    return path


def _scara_sdf(folder: Path, bodies, joints) -> Path:
    """The SCARA as SDFormat 1.7 (poses relative to the parent link, as the URDF's origins)."""
    pose = {"base": [0.0, 0.0, 0.0]}
    for _, _, parent, child, origin, _, _ in joints:
        pose[child] = [a + float(b) for a, b in zip(pose[parent], origin.split())]
    links = "".join(
        f'<link name="{n}"><pose>{" ".join(map(str, pose[n]))} 0 0 0</pose><inertial><pose>{c} 0 0 0</pose><mass>{m}</mass>'
        f"<inertia><ixx>{i}</ixx><iyy>{i}</iyy><izz>{i}</izz><ixy>0</ixy><ixz>0</ixz><iyz>0</iyz></inertia></inertial></link>"
        for n, m, c, i in bodies)
    js = '<joint name="fix" type="fixed"><parent>world</parent><child>base</child></joint>' + "".join(
        f'<joint name="{n}" type="{t}"><parent>{p}</parent><child>{c}</child><axis><xyz>0 0 1</xyz>'
        f"<limit><lower>{lo}</lower><upper>{hi}</upper><effort>{60 if t == 'prismatic' else 40}</effort>"
        f"<velocity>{0.5 if t == 'prismatic' else 2}</velocity></limit></axis></joint>"
        for n, t, p, c, _, lo, hi in joints)
    path = folder / "scara.sdf"
    path.write_text(f'<?xml version="1.0"?><sdf version="1.7"><model name="scara">{links}{js}</model></sdf>')
    return path


def without_inertials(model: Path, folder: Path) -> Path:
    """A copy of ``model`` with every ``<inertial>`` removed, as ROS-Industrial descriptions ship."""
    import re

    text = re.sub(r"<inertial>.*?</inertial>", "", Path(model).read_text(), flags=re.S)
    path = Path(folder) / f"{Path(model).stem}_no_inertials{Path(model).suffix}"
    path.write_text(text)
    return path


def vertical_lift(folder: Path) -> Path:
    """One vertical prismatic joint carrying 2 kg (a lift, a quill on its own)."""
    path = Path(folder) / "lift.urdf"
    path.write_text(
        '<robot name="lift"><link name="world"/>' f'<link name="base">{_inertial(5)}</link><link name="carriage">{_inertial(2)}</link>'
        '<joint name="fix" type="fixed"><parent link="world"/><child link="base"/></joint>'
        '<joint name="lift" type="prismatic"><parent link="base"/><child link="carriage"/><origin xyz="0 0 0.3"/>'
        '<axis xyz="0 0 1"/><limit lower="-0.2" upper="0.2" effort="200" velocity="0.5"/></joint></robot>')
    return path
