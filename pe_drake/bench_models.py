# ruff: noqa: E501 (URDF/SDF text on one line per link)
"""Small unusual robots written as text, so the benchmarks and tests build them without
downloads: a SCARA, lifts, a model without inertials, a folding arm, a textured xacro, and the
10-joint two-arm robot nobody tuned pe_drake for (``bench solve``). Each builder writes the model
into ``folder`` and returns its path.
"""

from __future__ import annotations

import re
import struct
import zlib
from pathlib import Path

_I = '<inertial><origin xyz="{c}"/><mass value="{m}"/><inertia ixx="{i}" iyy="{i}" izz="{i}" ixy="0" ixz="0" iyz="0"/></inertial>'
_COLLISION = '<collision><origin xyz="{o}" rpy="{r}"/><geometry><cylinder radius="{rad}" length="{L}"/></geometry></collision>'
_JOINT = ('<joint name="{n}" type="{t}"><parent link="{p}"/><child link="{c}"/><origin xyz="{o}"/><axis xyz="{a}"/>'
          '<limit lower="{lo}" upper="{hi}" effort="{e}" velocity="{v}"/></joint>')


def _inertial(m: float, c: str = "0 0 0", i: float = 0.01) -> str:
    return _I.format(m=m, c=c, i=i)


def _cylinder(z: float, radius: float, length: float, along: str = "z") -> str:
    """A collision cylinder centred at ``z`` on the link's z axis (or lying along y)."""
    return _COLLISION.format(o=f"0 0 {z}", r="1.5708 0 0" if along == "y" else "0 0 0", rad=radius, L=length)


def _fixed(child: str) -> str:
    return f'<joint name="fix_{child}" type="fixed"><parent link="world"/><child link="{child}"/></joint>'


def _write(folder: str | Path, name: str, text: str) -> Path:
    path = Path(folder) / name
    path.write_text(text)
    return path


def folding_arm(folder: Path, margin: float = 0.05, collision: bool = False) -> tuple[Path, Path]:
    """A 3-joint arm whose hand can fold onto its base post, and a capsule file recording
    ``collision_margin``; ``collision``: with collision cylinders. Returns (urdf, capsule file)."""
    shapes = dict(base=(0.325, 0.06, 0.35), l2=(0.15, 0.04, 0.2), hand=(0.08, 0.04, 0.1)) if collision else {}
    inertials = dict(base=(5, "0 0 0.2"), l1=(1.5, "0 0 0.15"), l2=(1.5, "0 0 0.15"), hand=(0.5, "0 0 0.05"))
    links = ['<link name="world"/>'] + [
        f'<link name="{name}">{_inertial(*inertial)}' + (_cylinder(*shapes[name]) if name in shapes else "") + "</link>"
        for name, inertial in inertials.items()]
    joints = [_fixed("base")] + [
        _JOINT.format(n=f"j{k}", t="revolute", p=p, c=c, o=f"0 0 {z}", a="1 0 0", lo=-2.6, hi=2.6, e=80, v=2)
        for k, (p, c, z) in enumerate((("base", "l1", 0.6), ("l1", "l2", 0.3), ("l2", "hand", 0.3)), start=1)]
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


def png_1x1() -> bytes:
    """A 1×1 green PNG: the texture of :func:`textured_xacro` (no image file to ship)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 1, 1, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"\x00\x00\xff\x00")) + chunk(b"IEND", b""))


def textured_xacro(folder: Path) -> Path:
    """:func:`folding_arm` as a description package ``arm_description/`` whose xacro uses a
    property and a ``package://`` texture on every visual; returns the .urdf.xacro."""
    package = Path(folder) / "ws" / "arm_description"
    (package / "urdf").mkdir(parents=True, exist_ok=True)
    (package / "meshes").mkdir(exist_ok=True)
    (package / "package.xml").write_text("<package><name>arm_description</name></package>\n")
    (package / "meshes" / "skin.png").write_bytes(png_1x1())
    urdf = folding_arm(Path(folder), collision=True)[0].read_text()
    visual = ('<visual><geometry><cylinder radius="${radius}" length="0.1"/></geometry>'
              '<material name="skin"/></visual>')
    urdf = re.sub(r'(<link name="(?:base|l1|l2|hand)">)', r"\1" + visual, urdf)
    urdf = urdf.replace('<robot name="folding">', '<robot name="textured" xmlns:xacro="http://www.ros.org/wiki/xacro">'
                        '<xacro:property name="radius" value="0.03"/>'
                        '<material name="skin"><texture filename="package://arm_description/meshes/skin.png"/>'
                        '</material>', 1)
    return _write(package / "urdf", "arm.urdf.xacro", urdf)


#: The SCARA's bodies (name, mass [kg], CoM, principal moment [kg·m²]) and joints (name, type,
#: parent, child, origin, lower, upper): every axis vertical.
_SCARA_BODIES = (("base", 8.0, "0 0 0.2", 0.1), ("upper", 3.0, "0.2 0 0", 0.02), ("fore", 2.0, "0.15 0 0", 0.01),
                 ("quill", 1.0, "0 0 -0.1", 0.005), ("tool", 0.3, "0 0 -0.02", 0.001))
_SCARA_JOINTS = (("shoulder", "revolute", "base", "upper", "0 0 0.5", -2.5, 2.5),
                 ("elbow", "revolute", "upper", "fore", "0.35 0 0", -2.5, 2.5),
                 ("lift", "prismatic", "fore", "quill", "0.3 0 0", -0.15, 0.0),
                 ("wrist", "revolute", "quill", "tool", "0 0 -0.2", -3.0, 3.0))


def scara(folder: Path, fmt: str = "urdf") -> Path:
    """A SCARA, every axis parallel to gravity, with a prismatic quill; ``fmt``: "urdf" or "sdf"."""
    if fmt == "sdf":
        return _scara_sdf(Path(folder))
    links = ['<link name="world"/>'] + [f'<link name="{n}">{_inertial(m, c, i)}</link>' for n, m, c, i in _SCARA_BODIES]
    joints = [_fixed("base")] + [
        _JOINT.format(n=n, t=t, p=p, c=c, o=o, a="0 0 1", lo=lo, hi=hi, e=60 if t == "prismatic" else 40,
                      v=0.5 if t == "prismatic" else 2)
        for n, t, p, c, o, lo, hi in _SCARA_JOINTS]
    return _write(folder, "scara.urdf",
                  '<robot name="scara">' + "".join(links + joints) + "</robot>")


def _scara_sdf(folder: Path) -> Path:
    """The SCARA as SDFormat 1.7 (link poses in the model frame, from the URDF's origins)."""
    pose = {"base": [0.0, 0.0, 0.0]}
    for _, _, parent, child, origin, _, _ in _SCARA_JOINTS:
        pose[child] = [a + float(b) for a, b in zip(pose[parent], origin.split())]
    links = "".join(
        f'<link name="{n}"><pose>{" ".join(map(str, pose[n]))} 0 0 0</pose><inertial><pose>{c} 0 0 0</pose><mass>{m}</mass>'
        f"<inertia><ixx>{i}</ixx><iyy>{i}</iyy><izz>{i}</izz><ixy>0</ixy><ixz>0</ixz><iyz>0</iyz></inertia></inertial></link>"
        for n, m, c, i in _SCARA_BODIES)
    joints = '<joint name="fix" type="fixed"><parent>world</parent><child>base</child></joint>' + "".join(
        f'<joint name="{n}" type="{t}"><parent>{p}</parent><child>{c}</child><axis><xyz>0 0 1</xyz>'
        f"<limit><lower>{lo}</lower><upper>{hi}</upper><effort>{60 if t == 'prismatic' else 40}</effort>"
        f"<velocity>{0.5 if t == 'prismatic' else 2}</velocity></limit></axis></joint>"
        for n, t, p, c, _, lo, hi in _SCARA_JOINTS)
    return _write(folder, "scara.sdf",
                  f'<?xml version="1.0"?><sdf version="1.7"><model name="scara">{links}{joints}'
                  "</model></sdf>")


def dual_arm_lift(folder: Path) -> Path:
    """A torso on a vertical prismatic lift with two 3-joint arms, collision cylinders on every
    link."""
    links = ['<link name="world"/>', f'<link name="column">{_inertial(20, "0 0 0.4", 0.5)}{_cylinder(0.4, 0.08, 0.7)}</link>',
             f'<link name="torso">{_inertial(8, "0 0 0.15", 0.1)}{_cylinder(0.15, 0.1, 0.25)}</link>']
    joints = [_fixed("column"),
              _JOINT.format(n="lift", t="prismatic", p="column", c="torso", o="0 0 0.85", a="0 0 1", lo=-0.2, hi=0.2,
                            e=400, v=0.3)]
    for side, s in (("left", 1), ("right", -1)):
        links += [f'<link name="{side}_shoulder">{_inertial(1.0, f"0 {s * 0.03} 0", 0.003)}</link>',
                  f'<link name="{side}_upper">{_inertial(1.5, "0 0 -0.15", 0.01)}{_cylinder(-0.15, 0.04, 0.22)}</link>',
                  f'<link name="{side}_fore">{_inertial(1.0, "0 0 -0.12", 0.006)}{_cylinder(-0.13, 0.035, 0.18)}</link>']
        joints += [_JOINT.format(n=f"{side}_pitch", t="revolute", p="torso", c=f"{side}_shoulder", o=f"0 {s * 0.2} 0.25",
                                 a="0 1 0", lo=-2.0, hi=2.0, e=60, v=2),
                   _JOINT.format(n=f"{side}_roll", t="revolute", p=f"{side}_shoulder", c=f"{side}_upper",
                                 o=f"0 {s * 0.06} 0", a="1 0 0", lo=-0.3 if s > 0 else -1.5, hi=1.5 if s > 0 else 0.3,
                                 e=40, v=2),
                   _JOINT.format(n=f"{side}_elbow", t="revolute", p=f"{side}_upper", c=f"{side}_fore", o="0 0 -0.3",
                                 a="0 1 0", lo=-2.2, hi=0.1, e=30, v=2)]
    return _write(folder, "dual_arm_lift.urdf",
                  '<robot name="dual_arm_lift">' + "".join(links + joints) + "</robot>")


def vertical_lift(folder: Path) -> Path:
    """One vertical prismatic joint carrying 2 kg (a lift, a quill on its own)."""
    return _write(
        folder, "lift.urdf", '<robot name="lift"><link name="world"/>'
        f'<link name="base">{_inertial(5)}</link><link name="carriage">{_inertial(2)}</link>'
        + _fixed("base") + _JOINT.format(n="lift", t="prismatic", p="base", c="carriage", o="0 0 0.3", a="0 0 1",
                                         lo=-0.2, hi=0.2, e=200, v=0.5) + "</robot>")


def without_inertials(model: Path, folder: Path) -> Path:
    """A copy of ``model`` with every ``<inertial>`` removed, as ROS-Industrial descriptions ship."""
    text = re.sub(r"<inertial>.*?</inertial>", "", Path(model).read_text(), flags=re.S)
    return _write(folder, f"{Path(model).stem}_no_inertials{Path(model).suffix}", text)


#: (name, axis, lower, upper, velocity, effort, child link length [m], radius [m], mass [kg])
#: of each arm joint, from the shoulder to the wrist.
_ARM = (
    ("shoulder_pitch", "0 1 0", -2.6, 2.6, 2.6, 60.0, 0.12, 0.05, 1.8),
    ("shoulder_roll", "1 0 0", -1.5, 1.5, 2.6, 60.0, 0.28, 0.045, 1.6),
    ("elbow", "0 1 0", -2.4, 0.2, 3.0, 30.0, 0.26, 0.04, 1.1),
    ("wrist", "0 0 1", -2.8, 2.8, 3.5, 10.0, 0.10, 0.035, 0.6),
)


def _cylinder_link(mass: float, length: float, radius: float) -> str:
    """A solid cylinder's <inertial> and <collision> hanging ``length`` down z from the joint."""
    axial = 0.5 * mass * radius**2
    across = mass * (3 * radius**2 + length**2) / 12
    centre = f'<origin xyz="0 0 {-0.5 * length:.4f}"/>'
    return (
        f'<inertial>{centre}<mass value="{mass:.4f}"/>'
        f'<inertia ixx="{across:.6f}" ixy="0" ixz="0" iyy="{across:.6f}" iyz="0" izz="{axial:.6f}"/></inertial>'
        f'<collision>{centre}<geometry><cylinder radius="{radius:.3f}" length="{length:.3f}"/></geometry></collision>'
    )


def _box_link(name: str, mass: float, centre: str, size: str, inertia: tuple[float, float, float]) -> str:
    """A link with a box's <collision> and the given principal moments [kg·m²]."""
    ixx, iyy, izz = inertia
    return (
        f'<link name="{name}"><inertial><origin xyz="{centre}"/><mass value="{mass}"/>'
        f'<inertia ixx="{ixx}" ixy="0" ixz="0" iyy="{iyy}" iyz="0" izz="{izz}"/></inertial>'
        f'<collision><origin xyz="{centre}"/><geometry><box size="{size}"/></geometry></collision></link>'
    )


def write_two_arm_lift_urdf(folder: str | Path) -> Path:
    """Writes ``two_arm_lift.urdf``: joints ``lift`` (prismatic, z, 0–0.4 m), ``torso_yaw`` and
    ``{left,right}_{shoulder_pitch,shoulder_roll,elbow,wrist}``."""
    links = [
        _box_link("base", 20.0, "0 0 0.3", "0.4 0.4 0.6", (1.0, 1.0, 1.0)),
        _box_link("carriage", 6.0, "0 0 0.1", "0.3 0.3 0.2", (0.08, 0.06, 0.05)),
        _box_link("torso", 9.0, "0.02 0 0.25", "0.2 0.3 0.5", (0.30, 0.26, 0.09)),
    ]
    joints = [
        '<joint name="lift" type="prismatic"><parent link="base"/><child link="carriage"/>'
        '<origin xyz="0 0 0.6"/><axis xyz="0 0 1"/>'
        '<limit lower="0.0" upper="0.4" velocity="0.3" effort="600"/></joint>',
        '<joint name="torso_yaw" type="revolute"><parent link="carriage"/><child link="torso"/>'
        '<origin xyz="0 0 0.2"/><axis xyz="0 0 1"/>'
        '<limit lower="-2.5" upper="2.5" velocity="1.5" effort="150"/></joint>',
    ]
    for side, sign in (("left", 1.0), ("right", -1.0)):
        parent, origin = "torso", f"0 {0.22 * sign:.2f} 0.45"
        for k, (name, axis, lower, upper, velocity, effort, length, radius, mass) in enumerate(_ARM):
            child = f"{side}_{name}_link"
            # The arms differ a little (a real robot's two arms never weigh exactly the same).
            m = mass * (1.0 + 0.04 * sign * (k + 1))
            links.append(f'<link name="{child}">{_cylinder_link(m, length, radius)}</link>')
            joints.append(
                f'<joint name="{side}_{name}" type="revolute"><parent link="{parent}"/><child link="{child}"/>'
                f'<origin xyz="{origin}"/><axis xyz="{axis}"/>'
                f'<limit lower="{lower}" upper="{upper}" velocity="{velocity}" effort="{effort}"/></joint>'
            )
            parent, origin = child, f"0 0 {-length:.3f}"
    body = "\n  ".join(links + joints)
    return _write(folder, "two_arm_lift.urdf",
                  f'<?xml version="1.0"?>\n<robot name="two_arm_lift">\n  {body}\n</robot>\n')
