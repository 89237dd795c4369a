"""Robot models the benchmarks build themselves (no robot file to fetch, no config to write).

:func:`write_two_arm_lift_urdf` writes a 10-joint robot nobody tuned pe_drake for: a
prismatic lift, a turning torso and two 4-joint arms, each link a solid box or cylinder with
its own mass and size. ``python -m pe_drake.bench solve`` loads it the way a user would load
an unknown URDF: ``resolve_robot_config(path)`` (the defaults for a model without a config).
"""

from __future__ import annotations

from pathlib import Path

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


def two_arm_lift_urdf() -> str:
    """URDF text of the 10-joint two-arm robot (module docstring): joints ``lift``
    (prismatic, z, 0–0.4 m), ``torso_yaw`` and ``{left,right}_{shoulder_pitch,shoulder_roll,
    elbow,wrist}``."""
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
    return f'<?xml version="1.0"?>\n<robot name="two_arm_lift">\n  {body}\n</robot>\n'


def write_two_arm_lift_urdf(folder: str | Path) -> Path:
    """Writes :func:`two_arm_lift_urdf` as ``two_arm_lift.urdf`` in ``folder``; returns its path."""
    path = Path(folder) / "two_arm_lift.urdf"
    path.write_text(two_arm_lift_urdf())
    return path
