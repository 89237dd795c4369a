"""Writing an identified robot model: the original URDF with new ``<inertial>`` elements (Drake
keeps one body per link), everything else kept; mesh names Drake's loader does not know become
``file://`` URIs so the file works from any folder.
"""

from __future__ import annotations

import contextlib
import logging
import re
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from pe_drake.exceptions import ConfigError, UnknownNameError
from pe_drake.multibody.inertia import central_inertia, check_physically_valid, spatial_inertia_to_phi
from pe_drake.multibody.model_files import single_material_definitions, without_dangling_transmissions
from pe_drake.multibody.packages import example_robot_data_dir, resolve_package_uri

#: Packages the pe_drake loader always registers; their URIs are kept as they are.
KNOWN_PACKAGES = ("example-robot-data",)


def _fmt(x: float) -> str:
    return repr(float(x)) if x != 0 else "0"


def inertial_element(phi_b: np.ndarray, indent: str = "    ") -> ET.Element:
    """The ``<inertial>`` element of one body's 10 parameters, indented for a link at ``indent``."""
    m, p, I = central_inertia(np.asarray(phi_b, float))
    inertial = ET.Element("inertial")
    inertial.text = "\n" + indent + "  "
    origin = ET.SubElement(inertial, "origin", {"xyz": " ".join(_fmt(x) for x in p), "rpy": "0 0 0"})
    origin.tail = "\n" + indent + "  "
    mass = ET.SubElement(inertial, "mass", {"value": _fmt(m)})
    mass.tail = "\n" + indent + "  "
    inertia = ET.SubElement(inertial, "inertia", {
        "ixx": _fmt(I[0, 0]), "ixy": _fmt(I[0, 1]), "ixz": _fmt(I[0, 2]),
        "iyy": _fmt(I[1, 1]), "iyz": _fmt(I[1, 2]), "izz": _fmt(I[2, 2]),
    })
    inertia.tail = "\n" + indent
    return inertial


def _resolve_uri(uri: str, source: Path, package_map) -> str:
    """A mesh or texture URI of the URDF ``source`` that works from any folder."""
    if uri.startswith("package://"):
        package = uri[len("package://") :].split("/", 1)[0]
        if package in KNOWN_PACKAGES:
            return uri
        found = resolve_package_uri(uri, source)
        if found is not None:  # pe_drake's resolver: package.xml above the model, ROS paths
            return found.resolve().as_uri()
        try:
            return "file://" + str(Path(package_map.ResolveUrl(uri)).resolve())
        except Exception:  # unknown package: keep the URI (the caller's package path may know it)
            return uri
    if "://" in uri:
        return uri
    path = Path(uri)
    if not path.is_absolute():
        path = source.parent / path
    return "file://" + str(path.resolve())


def urdf_with_inertias(source: str | Path, body_names: Sequence[str], phi: np.ndarray, *,
                       check: bool = True) -> str:
    """The text of a URDF with the inertial of every listed link replaced.

    Args:
        body_names: links to rewrite (Drake body names = URDF link names), length nb.
        phi: their parameters, shape (10·nb,), about each link origin in the link frame.
        check: refuse physically invalid parameters (Drake's test) before writing.

    Raises:
        PhysicallyInvalidError: a body's parameters are not physically valid.
        ConfigError: the file is not a URDF, cannot be parsed, or lacks a listed link.
    """
    source = Path(source)
    if source.suffix.lower() != ".urdf":
        raise ConfigError(
            f"model export writes URDF files; '{source.name}' is not a .urdf (load the robot from "
            "its URDF to export an identified model)")
    phi = np.asarray(phi, float)
    if check:
        check_physically_valid(body_names, phi)
    try:
        parser = ET.XMLParser(target=ET.TreeBuilder(insert_comments=True))
        root = ET.fromstring(source.read_text(), parser=parser)
    except (OSError, ET.ParseError) as err:
        raise ConfigError(f"cannot read the URDF '{source}': {err}") from err
    links = {link.get("name"): link for link in root.iter("link")}
    missing = [b for b in body_names if b not in links]
    if missing:
        raise ConfigError(
            f"the URDF '{source.name}' has no link(s) {', '.join(missing)}; bodies added outside the "
            "file (e.g. a payload) cannot be exported to it")
    for b, name in enumerate(body_names):
        link = links[name]
        children = list(link)
        old = link.find("inertial")
        position = children.index(old) if old is not None else 0
        # Indent like the element it replaces (or the link's first child).
        before = (children[position - 1].tail if position > 0 else link.text) or ""
        indent = before.rsplit("\n", 1)[-1] if "\n" in before else "    "
        if old is not None:
            tail = old.tail
            link.remove(old)
        else:
            tail = "\n" + indent
            if not before.strip() and "\n" not in before:
                link.text = "\n" + indent
        new = inertial_element(phi[10 * b : 10 * b + 10], indent)
        new.tail = tail
        link.insert(position, new)
    _drop_zero_dof_mimics(root)
    from pydrake.multibody.parsing import PackageMap  # lazy: pydrake is heavy

    package_map = PackageMap()
    with contextlib.suppress(Exception):
        package_map.PopulateFromFolder(str(source.parent))
    for element in [*root.iter("mesh"), *root.iter("texture")]:  # textures too (issue 37, item 6)
        if element.get("filename"):
            element.set("filename", _resolve_uri(element.get("filename"), source, package_map))
    text = without_dangling_transmissions(ET.tostring(root, encoding="unicode"))[0]  # Drake refuses them
    header = f"<!-- {source.name} with identified inertial parameters (pe_drake) -->\n"
    return '<?xml version="1.0"?>\n' + header + text + "\n"


def _drop_zero_dof_mimics(root: ET.Element) -> None:
    """Removes ``<mimic>`` from fixed joints and from joints mimicking a fixed joint.

    Drake refuses a mimic on a 0-dof joint; the other mimic tags are kept for ROS tools.
    """
    kinds = {j.get("name"): j.get("type") for j in root.iter("joint")}
    for joint in root.iter("joint"):
        for mimic in joint.findall("mimic"):
            if joint.get("type") == "fixed" or kinds.get(mimic.get("joint")) in ("fixed", None):
                joint.remove(mimic)


def urdf_text_phi(text: str, body_names: Sequence[str]) -> np.ndarray:
    """Each body's 10 parameters as Drake reads URDF text, shape (10·len(body_names),).

    ConfigError when Drake refuses the text, UnknownNameError for a body it does not have."""
    from pydrake.multibody.parsing import Parser  # lazy: pydrake is heavy
    from pydrake.multibody.plant import MultibodyPlant

    plant = MultibodyPlant(0.0)
    parser = Parser(plant)
    with contextlib.suppress(ConfigError):
        parser.package_map().Add("example-robot-data", str(example_robot_data_dir()))
    drake_logger = logging.getLogger("drake")
    level = drake_logger.level
    drake_logger.setLevel(logging.ERROR)
    try:
        parser.AddModelsFromString(single_material_definitions(text)[0], "urdf")
    except Exception as err:
        raise ConfigError(f"Drake refuses the exported URDF: {err}") from err
    finally:
        drake_logger.setLevel(level)
    missing = [b for b in body_names if not plant.HasBodyNamed(b)]
    if missing:
        raise UnknownNameError("link", missing[0], [], where="exported URDF")
    return np.concatenate([spatial_inertia_to_phi(plant.GetBodyByName(b).default_spatial_inertia())
                           for b in body_names]) if body_names else np.zeros(0)


def verify_urdf_text(text: str, body_names: Sequence[str], phi: np.ndarray,
                     tolerance: float = 1e-9) -> None:
    """Parses URDF text with Drake and compares each body's parameters with ``phi``.

    ConfigError when Drake refuses the text, or a body's parameters differ by more than
    ``tolerance`` relative to its largest parameter."""
    read, phi = urdf_text_phi(text, body_names), np.asarray(phi, float)
    for b, name in enumerate(body_names):
        got, want = read[10 * b : 10 * b + 10], phi[10 * b : 10 * b + 10]
        scale = max(float(np.max(np.abs(want))), 1e-12)
        if float(np.max(np.abs(got - want))) > tolerance * scale:
            raise ConfigError(
                f"the exported URDF does not reproduce body '{name}': Drake reads {got.tolist()}, "
                f"expected {want.tolist()}")


def joint_dynamics(text: str, damping: dict[str, float], rotor_inertia: dict[str, float],
                   friction: dict[str, float] | None = None) -> str:
    """URDF text with each joint's damping [N·m·s/rad], rotor inertia [kg·m²] and friction [N·m].

    The rotor inertia is Drake's ``drake:rotor_inertia`` of a gear-ratio-1 actuator (the
    armature). Drake ignores ``<dynamics friction>``, but pe_drake reads it as the model file's
    friction (``Robot.joint_friction``), so a written value replaces the source's."""
    for name, value in damping.items():
        text = _set_joint_dynamics(text, name, "damping", float(value))
    for name, value in (friction or {}).items():
        text = _set_joint_dynamics(text, name, "friction", float(value))
    extra = []
    for name, value in rotor_inertia.items():
        extra.append(
            f'  <transmission name="pe_drake_armature_{name}">\n'
            "    <type>transmission_interface/SimpleTransmission</type>\n"
            f'    <joint name="{name}"><hardwareInterface>EffortJointInterface</hardwareInterface></joint>\n'
            f'    <actuator name="pe_drake_actuator_{name}">\n'
            "      <mechanicalReduction>1</mechanicalReduction>\n"
            f'      <drake:rotor_inertia value="{_num(value)}"/>\n'
            '      <drake:gear_ratio value="1.0"/>\n'
            "    </actuator>\n  </transmission>\n")
    if extra:
        head, sep, tail = text.rpartition("</robot>")
        text = head + "".join(extra) + sep + tail
    if "xmlns:drake" not in text:
        text = re.sub(r"<robot\b", '<robot xmlns:drake="http://drake.mit.edu"', text, count=1)
    return text


def payload_link_text(name: str, parent: str, payload) -> str:
    """URDF text of a link ``name`` holding a payload (in ``parent``'s frame), welded to it."""
    m, p, I = central_inertia(payload.phi)
    return (f'  <link name="{name}">\n    <inertial>\n'
            f'      <origin xyz="{_num(p[0])} {_num(p[1])} {_num(p[2])}" rpy="0 0 0"/>\n'
            f'      <mass value="{_num(m)}"/>\n'
            f'      <inertia ixx="{_num(I[0, 0])}" ixy="{_num(I[0, 1])}" ixz="{_num(I[0, 2])}" iyy="{_num(I[1, 1])}" '
            f'iyz="{_num(I[1, 2])}" izz="{_num(I[2, 2])}"/>\n    </inertial>\n  </link>\n'
            f'  <joint name="{name}_weld" type="fixed">\n'
            f'    <parent link="{parent}"/>\n    <child link="{name}"/>\n'
            '    <origin xyz="0 0 0" rpy="0 0 0"/>\n  </joint>\n')


def _num(x) -> str:
    return repr(float(x))


def _set_joint_dynamics(text: str, joint: str, attribute: str, value: float) -> str:
    """Sets ``attribute`` in the joint's <dynamics> element (added when missing)."""
    pattern = re.compile(r'(<joint\b[^>]*\bname="' + re.escape(joint) + r'"[^>]*>)(.*?)(</joint>)', re.S)
    match = pattern.search(text)
    if match is None:
        return text
    body = match.group(2)
    dyn = re.search(r"<dynamics\b[^>]*/>", body)
    setting = f'{attribute}="{_num(value)}"'
    if dyn:
        element = dyn.group(0)
        if re.search(r'\b' + attribute + r'="[^"]*"', element):
            new = re.sub(r'\b' + attribute + r'="[^"]*"', setting, element)
        else:
            new = element.replace("<dynamics", f"<dynamics {setting}", 1)
        body = body.replace(element, new, 1)
    else:
        body = body.rstrip() + f"\n    <dynamics {setting}/>\n  "
    return text[: match.start(2)] + body + text[match.end(2) :]
