"""Model files as Drake and pe_drake read them: xacro expanded, package URIs resolved, and the
URDF constructs Drake refuses pre-processed.

:func:`loadable_model_path` turns ``robot.model`` into the one file every later step reads;
:func:`drake_model_text` prepares its text for Drake's parser (notes say what changed).
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import re
import threading
from collections.abc import Mapping
from pathlib import Path

from pe_drake.exceptions import ConfigError
from pe_drake.io_utils import atomic_write_text
from pe_drake.multibody.packages import example_robot_data_dir
from pe_drake.multibody.mesh_policy import allowed_mesh_roots, decoded_character_references, mesh_file_refusal
from pe_drake.multibody.model_references import (check_every_name, check_mjcf_files,
                                                 checked_sdf_text, without_refused_textures)
from pe_drake.multibody.collada_up_axis import turned_dae_visuals
from pe_drake.multibody.meshes import absolute_mesh_paths, default_cache_dir, stl_visuals_to_obj, without_refused_visuals
from pe_drake.multibody.packages import (find_package, manifest_name, register_packages,
                                         resolve_package_uri, unknown_package_message,
                                         used_packages)
from pe_drake.multibody.urdf_checks import check_joint_types, has_entities
from pe_drake.multibody.xacro_sandbox import TRUST_HINT, sandboxed

#: Suffixes of model files pe_drake reads.
MODEL_SUFFIXES = (".urdf", ".sdf", ".xml", ".xacro")

_FILE_NAME = re.compile(r"(<(?:mesh|texture)\b[^>]*?(?<![\w:.-])filename\s*=\s*)([\"'])(.*?)\2", re.S)
_ROOTS_FILE = "mesh_roots.txt"
_MATERIAL = re.compile(r"<material\b([^>]*?)(/>|>(.*?)</material\s*>)", re.S)
_LINK = re.compile(r"<link\b[^>]*?(/>|>.*?</link\s*>)", re.S)
_NAME_ATTR = re.compile(r"""(?<![\w:.-])name\s*=\s*(["'])(.*?)\1""", re.S)
_TRANSMISSION = re.compile(r"<transmission\b.*?</transmission\s*>", re.S)
_MIMIC = re.compile(r"<mimic\b[^>]*/>|<mimic\b[^>]*>.*?</mimic\s*>", re.S)
_XACRO_LOCK = threading.Lock()  # xacro keeps its state in module globals


def is_xacro(path: str | Path) -> bool:
    """Whether a model file is a xacro file (``.xacro``, e.g. ``arm.urdf.xacro``)."""
    return Path(path).suffix.lower() == ".xacro"


def model_stem(path: str | Path) -> str:
    """A model's name from its file: ``my_arm`` for ``my_arm.urdf`` and ``my_arm.urdf.xacro``."""
    name = Path(path).name
    for suffix in (".urdf.xacro", ".xacro", *MODEL_SUFFIXES):
        if name.lower().endswith(suffix):
            return name[: -len(suffix)]
    return Path(path).stem


def expand_xacro(path: str | Path, packages: Mapping[str, str] | None = None,
                 mappings: Mapping[str, str] | None = None, *, trust: bool = False) -> str:
    """The URDF text of a xacro file.

    ``$(find pkg)`` goes through :func:`~pe_drake.multibody.packages.find_package`. A xacro is a
    program: unless ``trust``, it runs in :func:`~pe_drake.multibody.xacro_sandbox.sandboxed`.

    Args:
        mappings: xacro arguments {name: value} (``xacro file.xacro name:=value``).
        trust: run the file with xacro's full Python (``--trust-xacro``, ``robot.trust_xacro``).

    Raises:
        ConfigError: xacro is missing, a package is unknown, xacro refuses the file, or an
            untrusted file uses a refused construct.
    """
    try:
        import xacro  # lazy: only xacro models need it
        from xacro import substitution_args
    except ImportError as err:  # pragma: no cover - xacro is a dependency
        raise ConfigError(f"reading '{Path(path).name}' needs the xacro package: pip install xacro") from err
    path = Path(path).resolve()
    found: list[str] = []

    def find(package: str) -> str:
        folder = find_package(package, path, packages)
        found.append(os.path.realpath(folder))
        return str(folder)

    home = next((f for f in path.parents if manifest_name(f) is not None), None)
    with _XACRO_LOCK:
        saved = substitution_args._eval_find, substitution_args._eval_dict.get("find")
        substitution_args._eval_find = find  # used by $(find ...) and by $(eval find(...))
        substitution_args._eval_dict["find"] = find
        try:
            with contextlib.nullcontext() if trust else sandboxed(path, home, found):
                doc = xacro.process_file(str(path), mappings=dict(mappings or {}))
            return doc.toprettyxml(indent="  ")
        except ConfigError:
            raise
        except Exception as err:  # xacro raises XacroException, SubstitutionException, XML errors
            # a builtin the sandbox withholds (open, exec, getattr) is a NameError inside xacro
            hint = f"; {TRUST_HINT}" if not trust and "is not defined" in str(err) else ""
            raise ConfigError(f"xacro could not expand '{path}': {err}{hint}") from err
        finally:
            substitution_args._eval_find, substitution_args._eval_dict["find"] = saved


def resolved_mesh_uris(text: str, model_path: str | Path, packages: Mapping[str, str] | None = None) -> str:
    """Every mesh and texture name of a URDF as an absolute ``file://`` URI where it is found.

    Names are resolved from the model file the user named, not from the copy in the cache; names
    that cannot be found stay for Drake to report."""
    model_path = Path(model_path).resolve()

    def absolute(match: re.Match) -> str:
        name = match.group(3)
        if name.startswith("package://"):
            found = resolve_package_uri(name, model_path, packages)
        elif name.startswith("file://"):
            return match.group(0)
        else:
            found = Path(name) if Path(name).is_absolute() else model_path.parent / name
            found = found if found.exists() else None
        if found is None:
            return match.group(0)
        return f"{match.group(1)}{match.group(2)}{found.resolve().as_uri()}{match.group(2)}"

    return _FILE_NAME.sub(absolute, text)


def cached_model_roots(model_path: str | Path) -> list[str] | None:
    """The folders a cached model may read meshes from, or None for a model outside the cache."""
    cache = os.path.realpath(default_cache_dir())
    real = os.path.realpath(model_path)
    if not real.startswith(cache + os.sep):
        return None
    record = Path(real).parent / _ROOTS_FILE
    try:
        return [line for line in record.read_text().splitlines() if line.strip()]
    except OSError:  # an older cache entry: the cache and example-robot-data only
        return [cache, *_always_allowed()]


def _always_allowed() -> list[str]:
    with contextlib.suppress(ConfigError):
        return [os.path.realpath(example_robot_data_dir())]
    return []


def loadable_model_path(model_path: str | Path, packages: Mapping[str, str] | None = None, *,
                        trust_xacro: bool = False) -> Path:
    """The file later steps read for a model.

    Returns:
        ``model_path`` itself, or (for a xacro, or a URDF using ``packages``) a URDF in
        ``<mesh cache>/models/<hash>/`` with absolute mesh URIs and the folders its meshes may
        come from recorded beside it (:func:`cached_model_roots`).
    """
    model_path = Path(model_path)
    packages = dict(packages or {})
    source = read_model_text(model_path)  # a pipe or /dev/zero named as the model: refused, not read
    if is_xacro(model_path):
        text = expand_xacro(model_path, packages, trust=trust_xacro)
    elif model_path.suffix.lower() == ".urdf" and set(used_packages(source)) & set(packages):
        text = source
    else:
        return model_path
    text = decoded_character_references(text)
    roots = allowed_mesh_roots(model_path, text, packages, extra=(default_cache_dir(), *_always_allowed()))
    text = resolved_mesh_uris(text, model_path, packages)
    digest = hashlib.blake2b(f"{model_path.resolve()}\n{text}".encode(), digest_size=8).hexdigest()
    target = default_cache_dir() / "models" / digest / f"{model_stem(model_path)}.urdf"
    atomic_write_text(target.parent / _ROOTS_FILE, "\n".join(roots) + "\n")  # before the model: never unconfined
    if not target.is_file() or target.read_text() != text:
        atomic_write_text(target, text)
    return target


def without_mimic(text: str) -> tuple[str, list[str]]:
    """URDF text without ``<mimic>`` tags, and a note naming the joints that had one.

    Drake refuses a mimic joint driven by a 0-dof joint, and a mimic couples joints pe_drake may
    lock; the joints become independent.
    """
    joints = []
    for match in re.finditer(r"<joint\b[^>]*?\bname\s*=\s*([\"'])(.*?)\1[^>]*>(.*?)</joint\s*>", text, re.S):
        if _MIMIC.search(match.group(3)):
            joints.append(match.group(2))
    if not joints:
        return text, []
    shown = ", ".join(joints[:6]) + (f" and {len(joints) - 6} more" if len(joints) > 6 else "")
    return _MIMIC.sub("", text), [f"mimic tags of {len(joints)} joint(s) ignored ({shown}): each is an independent joint"]


def without_dangling_transmissions(text: str) -> tuple[str, list[str]]:
    """URDF text without ``<transmission>`` elements naming an undefined joint, and a note.

    Drake refuses the whole file for one; ROS tools skip it, and pe_drake does not read
    transmissions (gear ratios come from ``robot.transmission``).
    """
    defined = {m.group(2) for m in re.finditer(r"<joint\b[^>]*?(?<![\w:.-])name\s*=\s*([\"'])(.*?)\1[^>]*?>", text)
               if "type" in m.group(0)}
    dropped: list[str] = []

    def one(match: re.Match) -> str:
        named = [m.group(2) for m in re.finditer(r"<joint\b[^>]*?(?<![\w:.-])name\s*=\s*([\"'])(.*?)\1", match.group(0))]
        missing = [name for name in named if name not in defined]
        if not missing:
            return match.group(0)
        dropped.extend(missing)
        return ""

    text = _TRANSMISSION.sub(one, text)
    if not dropped:
        return text, []
    return text, [f"transmission element(s) of joint(s) the file does not define ignored: {', '.join(dropped)}"]


def single_material_definitions(text: str) -> tuple[str, list[str]]:
    """URDF text in which each named material is defined once, at its first use, and notes.

    Drake refuses a repeated definition, a reference before the definition and one defined
    nowhere, which ROS tools accept. Later definitions become references; a name defined nowhere
    is dropped.
    """
    links = [m.span() for m in _LINK.finditer(text)]
    definitions: dict[str, str] = {}
    global_names: set[str] = set()  # defined under <robot> itself: Drake reads those first, wherever they are
    for match in _MATERIAL.finditer(text):
        name_match = _NAME_ATTR.search(match.group(1))
        if name_match is not None and match.group(3) is not None and match.group(3).strip():
            definitions.setdefault(name_match.group(2), match.group(0))
            if not any(a <= match.start() < b for a, b in links):
                global_names.add(name_match.group(2))
    used: set[str] = set()
    undefined: set[str] = set()
    repeated: dict[str, int] = {}
    moved: list[str] = []

    def one(match: re.Match) -> str:
        name_match = _NAME_ATTR.search(match.group(1))
        if name_match is None:
            return match.group(0)
        name = name_match.group(2)
        if name not in definitions:
            if match.group(3) is None or not match.group(3).strip():
                undefined.add(name)
                return ""  # a name defined nowhere: the visual keeps Drake's default colour
            return match.group(0)
        defines = match.group(3) is not None and bool(match.group(3).strip())
        if name in global_names:  # Drake reads these first: uses anywhere are fine
            if not defines:
                return match.group(0)
            if not any(a <= match.start() < b for a, b in links) and name not in used:
                used.add(name)
                return match.group(0)  # the (first) global definition
            repeated[name] = repeated.get(name, 0) + 1
            return "" if not any(a <= match.start() < b for a, b in links) else f"<material{match.group(1).rstrip()}/>"
        if name not in used:
            used.add(name)
            if defines:
                return match.group(0)
            moved.append(name)
            return definitions[name]  # the definition, brought forward to the first use
        if defines:
            if not (name in moved and match.group(0) == definitions[name]):
                repeated[name] = repeated.get(name, 0) + 1
            return f"<material{match.group(1).rstrip()}/>"
        return match.group(0)

    out = _MATERIAL.sub(one, text)
    notes = []
    if repeated:
        listed = ", ".join(f"'{k}' ({v}×)" for k, v in repeated.items())
        notes.append(f"repeated material definitions kept once (the first; Drake refuses repeats): {listed}")
    if moved:
        notes.append("material definitions moved to their first use (Drake refuses a use before the "
                     f"definition): {', '.join(repr(m) for m in moved)}")
    if undefined:
        notes.append("materials used but defined nowhere dropped (the default colour; Drake refuses them): "
                     + ", ".join(repr(m) for m in sorted(undefined)))
    return (out, notes) if notes else (text, [])


def drake_model_text(model_path: Path, obj_visuals: bool, packages: dict | None = None) -> tuple[str, list[str]]:
    """The model file's text as Drake parses it, and notes of what was changed for Drake.

    Every file the model names passes the read policy (:mod:`~pe_drake.multibody.mesh_policy`),
    checked after XML character references are decoded, as Drake's parser reads the names."""
    text = decoded_character_references(read_model_text(model_path))
    notes: list[str] = []
    suffix = model_path.suffix.lower()
    roots = _mesh_roots(model_path, text, packages)
    if suffix == ".sdf":
        text, notes = checked_sdf_text(text, model_path, roots, packages)
        check_every_name(text, model_path, roots, packages)
    elif suffix == ".xml":
        check_mjcf_files(text, model_path, roots)
    if suffix == ".urdf":
        check_joint_types(text, model_path)  # floating/ball joints: named, with what is supported
        # Drake cannot build convex hulls of STL/DAE collision meshes (BUILD_NOTES.md);
        # collision is our own capsules. Mimic tags would couple joints we may lock.
        text = re.sub(r"<collision\b.*?</collision\s*>", "", text, flags=re.S)
        text, mimic_notes = without_mimic(text)
        text, material_notes = single_material_definitions(text)  # Kinova JACO2, TALOS full
        text, transmission_notes = without_dangling_transmissions(text)  # TALOS left arm
        notes += mimic_notes + material_notes + transmission_notes
        if "package:///" in text:  # TALOS full writes package:///<name>/...: an empty package for Drake
            text = text.replace("package:///", "package://")
            notes.append("package:/// URIs read as package:// (an empty package name)")
        text = absolute_mesh_paths(text, model_path)  # parsed from a string: no folder to resolve against
        text, refused = without_refused_visuals(text, model_path, roots, packages)
        text, refused_textures = without_refused_textures(text, model_path, roots, packages)
        notes += refused + refused_textures  # a visual naming /etc/passwd or a key would be embedded in playback.html
        check_every_name(text, model_path, roots, packages)
        if obj_visuals:
            text = stl_visuals_to_obj(text, model_path, packages=packages)
            text = turned_dae_visuals(text, model_path, packages)  # iCub's: Meshcat draws a DAE as written
    return text, notes


def read_model_text(model_path: Path) -> str:
    """A model file's text; ConfigError for a pipe, a device, a folder or an oversize file."""
    refusal = mesh_file_refusal(model_path, MODEL_SUFFIXES, "model")
    if refusal is not None:
        raise ConfigError(refusal)
    try:
        return model_path.read_text()
    except (OSError, UnicodeDecodeError) as err:
        raise ConfigError(f"cannot read the model '{model_path}': {err}") from err


def _mesh_roots(model_path: Path, text: str, packages: dict | None) -> list[str]:
    """Where the model's meshes may lie (for a cached model, those of the file it came from)."""
    cached = cached_model_roots(model_path)
    if cached is not None:
        return cached
    return allowed_mesh_roots(model_path, text, packages, extra=(default_cache_dir(), *_always_allowed()))


def finalize_plant(plant, model_path: Path) -> None:
    """``plant.Finalize()``, refusing a closed kinematic loop or another structure Drake refuses."""
    try:
        plant.Finalize()
    except RuntimeError as err:
        loop = "loops in the system graph" in str(err)
        what = "a closed kinematic loop (e.g. a four-bar or a parallel linkage)" if loop else "a structure Drake refuses"
        raise ConfigError(
            f"'{model_path.name}' has {what}: {str(err).splitlines()[0][:300]}. pe_drake supports kinematic trees of "
            "revolute, continuous and prismatic joints (fixed joints welded), one root link welded to the world; "
            "cut a loop by deleting one of its joints (or making it fixed), or lock the loop's joints"
        ) from err


def check_world_joints(plant, models, model_path: Path) -> None:
    """Refuses a movable joint from the world: pe_drake welds the root link to the world."""
    world = plant.world_body().index()
    for m in models:
        for index in plant.GetJointIndices(m):
            joint = plant.get_joint(index)
            if joint.parent_body().index() == world and joint.num_positions() > 0:
                raise ConfigError(
                    f"'{model_path.name}': joint '{joint.name()}' connects the world to link "
                    f"'{joint.child_body().name()}' as a {joint.type_name()} joint; pe_drake supports fixed-base "
                    "robots whose root link is welded to the world (by a fixed world joint or by pe_drake, at "
                    "robot.base_position / robot.base_quaternion_wxyz) with revolute and prismatic joints in a "
                    "tree. Make that joint fixed or delete it, and mount the root link with robot.base_position"
                )


def parse_models(plant, text: str, model_path: Path, packages: dict | None = None) -> list:
    """Adds the model to the plant, every ``package://`` it uses registered; returns its instances.

    ConfigError for an unknown package, or Drake's message when it cannot parse the text."""
    from pydrake.multibody.parsing import Parser  # lazy: pydrake is heavy

    parser = Parser(plant)
    unknown = register_packages(parser.package_map(), text, model_path, packages)
    drake_logger = logging.getLogger("drake")
    level = drake_logger.level
    drake_logger.setLevel(logging.ERROR)  # unsupported ROS tags (gazebo, transmission)
    try:
        return parser.AddModelsFromString(text, model_path.suffix.lstrip(".").lower())
    except Exception as err:  # Drake raises RuntimeError with its parser message
        hint = "".join(f"; {unknown_package_message(p, model_path)}" for p in unknown if p in str(err))
        if has_entities(text) and "&" in str(err):
            hint += ("; the file's <!DOCTYPE> defines entities, which Drake does not expand (it reads '&name;' "
                     "as that text): write their values in place")
        raise ConfigError(f"Drake could not parse '{model_path}': {err}{hint}") from err
    finally:
        drake_logger.setLevel(level)
