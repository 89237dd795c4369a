"""Which mesh files pe_drake and Drake may read: a model written by someone else must not copy
an arbitrary file into ``playback.html`` (Meshcat embeds every visual mesh whole), nor hang a run
on a named pipe or read ``/dev/zero`` until memory runs out.

A mesh is read only if its real path (symlinks resolved) is a regular file with a mesh suffix,
at most :data:`MAX_MESH_BYTES`, and, for a model's visuals, lies under the model's folder, the
root of a package the model uses (and that root's real path, for colcon ``--symlink-install``),
pe_drake's mesh cache or example-robot-data. A ``package://`` name stays inside its package
(no ``..`` above the root). The files a mesh names itself (an OBJ's ``mtllib`` and the
material's ``map_*`` images, a glTF's ``buffers``/``images`` ``uri``, a COLLADA image's
``init_from``) pass the same checks with their own suffixes: Meshcat embeds them too.
Names are checked as the XML parser reads them: character references (``&#46;``) are
decoded first (:func:`decoded_character_references`).
"""

from __future__ import annotations

import json
import os
import re
import stat
import struct
from collections.abc import Iterable, Mapping
from pathlib import Path
from urllib.parse import unquote

from pe_drake import limits
from pe_drake.multibody.packages import package_roots, resolve_package_uri, used_packages

#: Suffixes of the mesh formats pe_drake or Drake read.
MESH_SUFFIXES = (".stl", ".obj", ".dae", ".gltf", ".glb", ".ply", ".vtk")
#: Suffixes of the files a mesh may name (materials, textures, glTF buffers).
REFERENCE_SUFFIXES = (".mtl", ".png", ".jpg", ".jpeg", ".bmp", ".tga", ".gif", ".ktx2", ".webp", ".bin")
#: Largest mesh file read [bytes] by default (:data:`pe_drake.limits.MESH` overrides it).
MAX_MESH_BYTES = 256 * 2**20


_CHARACTER_REFERENCE = re.compile(r"&#(?:[xX]([0-9a-fA-F]{1,8})|([0-9]{1,10}));")
_KEPT_ESCAPED = {"<": "&lt;", "&": "&amp;", '"': "&quot;", "'": "&apos;", ">": "&gt;"}


def decoded_character_references(text: str) -> str:
    """XML text with its numeric character references (``&#46;``, ``&#x2e;``) written as the
    characters they stand for, so that a check of the raw text sees the names the XML parser
    will read (tinyxml2 decodes them after pe_drake's checks ran). Markup characters and
    control characters stay escaped."""

    def one(match: re.Match) -> str:
        code = int(match.group(1), 16) if match.group(1) else int(match.group(2))
        if code < 0x20 or code > 0x10FFFF or 0xD800 <= code <= 0xDFFF:
            return match.group(0)
        char = chr(code)
        return _KEPT_ESCAPED.get(char, char)

    return _CHARACTER_REFERENCE.sub(one, text)


def mesh_file_refusal(path: str | Path, suffixes: tuple[str, ...] = MESH_SUFFIXES, what: str = "mesh",
                      kind: str | None = None) -> str | None:
    """Why the mesh file ``path`` (or, with ``suffixes``, ``what`` and ``kind``, another file a
    model reads) must not be read (a sentence naming the path and the rule), or None."""
    real = os.path.realpath(path)
    shown = f"{what} '{path}'" + (f" (-> {real})" if real != os.path.abspath(path) else "")
    if Path(real).suffix.lower() not in suffixes:
        return f"{shown} is not a {kind or what} file: only {', '.join(suffixes)} files are read"
    try:
        info = os.stat(real)
    except OSError as err:
        return f"{shown} cannot be read: {err.strerror}"
    if not stat.S_ISREG(info.st_mode):
        return f"{shown} is not a regular file (a pipe, a device or a folder): only regular files are read"
    if info.st_size > limits.in_bytes(limits.MESH):
        return f"{shown} has {info.st_size / 2**20:.0f} MB, over {limits.describe(limits.MESH)}"
    return None


def allowed_mesh_roots(
    model_path: str | Path, text: str, packages: Mapping[str, str] | None, extra: Iterable[str | Path] = ()
) -> list[str]:
    """The real paths under which a model's visual meshes may lie: its folder, the roots of the
    packages its text uses (each as found and as its real path) and ``extra`` folders."""
    roots = [Path(model_path).resolve().parent, *map(Path, extra)]
    for name in used_packages(text):
        roots += package_roots(name, model_path, packages)
    out = []
    for root in roots:
        out += [os.path.abspath(root), os.path.realpath(root)]
    return sorted(set(out))


def _is_under(real: str, roots: Iterable[str]) -> bool:
    return any(real == r or real.startswith(r.rstrip(os.sep) + os.sep) for r in roots)


def package_uri_refusal(name: str) -> str | None:
    """Why a ``package://`` or ``model://`` name must not be followed: a path that climbs above
    its package's root (``package://arm/../../secret/cad.obj``), or None."""
    scheme = next((s for s in ("package://", "model://") if name.startswith(s)), None)
    if scheme is None:
        return None
    rest = name[len(scheme):].lstrip("/").partition("/")[2]
    normal = os.path.normpath(rest) if rest else ""
    if os.path.isabs(rest) or normal == ".." or normal.startswith(".." + os.sep) or "\\" in rest:
        return f"'{name}' leaves its package's folder: a package:// name is read only inside its package"
    return None


def _mesh_file(name: str, model_path: Path, packages: Mapping[str, str] | None) -> Path | None:
    if name.startswith(("package://", "model://")):
        name = "package://" + name.split("://", 1)[1]
        return resolve_package_uri(name, model_path, packages)
    if name.startswith("file://"):
        name = name[len("file://"):]
    path = Path(name)
    return path if path.is_absolute() else model_path.parent / path


def visual_mesh_refusal(
    name: str, model_path: str | Path, roots: Iterable[str] | None, packages: Mapping[str, str] | None = None
) -> str | None:
    """Why a visual mesh ``filename`` of a model must not be read, or None.

    Args:
        name: the ``filename`` attribute (``package://``, ``file://``, absolute or relative).
        model_path: the model file.
        roots: :func:`allowed_mesh_roots`, or None to check only the file itself.
        packages: the config's ``robot.packages`` map.
    """
    refusal = package_uri_refusal(name)
    if refusal is not None:
        return refusal
    path = _mesh_file(name, Path(model_path), packages)
    if path is None or not os.path.lexists(path):
        return None  # a missing mesh: Drake names it
    refusal = mesh_file_refusal(path)
    if refusal is None and roots is not None and not _is_under(os.path.realpath(path), roots):
        refusal = _outside(name, path)
    return refusal or referenced_file_refusal(Path(path), roots)


def _outside(name: str, path: str | Path, what: str = "mesh") -> str:
    return (f"{what} '{name}' is {os.path.realpath(path)}, outside the model's folder, its packages and "
            "pe_drake's mesh cache: meshes and the files they name are read only from there")


def referenced_file_refusal(mesh: Path, roots: Iterable[str] | None) -> str | None:
    """Why a file that the mesh ``mesh`` names must not be read (see the module docstring),
    or None when every one may."""
    suffix = mesh.suffix.lower()
    try:
        if suffix == ".obj":
            return _obj_references(mesh, roots)
        names = {".gltf": _gltf_uris, ".glb": _glb_uris, ".dae": _dae_images}.get(suffix)
        for name in names(mesh) if names else ():
            refusal = _reference_refusal(name, mesh, roots)
            if refusal:
                return refusal
    except (OSError, ValueError, UnicodeDecodeError) as err:
        return f"mesh '{mesh}' cannot be read: {err}"
    return None


def _reference_refusal(name: str, mesh: Path, roots: Iterable[str] | None) -> str | None:
    """Checks a name as written and, percent-decoded, as a URI reader may read it."""
    for spelling in dict.fromkeys((name, unquote(name))):
        refusal = _one_reference_refusal(spelling, mesh, roots)
        if refusal:
            return refusal
    return None


def _one_reference_refusal(name: str, mesh: Path, roots: Iterable[str] | None) -> str | None:
    if name.startswith("data:"):
        return None  # embedded in the mesh file itself
    if name.startswith("file://"):
        name = name[len("file://"):]
    elif "://" in name:
        return f"mesh '{mesh}' names '{name}': only files beside the mesh are read"
    path = Path(name) if os.path.isabs(name) else mesh.parent / name
    if not os.path.lexists(path):
        return None  # a missing texture: drawn without it
    refusal = mesh_file_refusal(path, REFERENCE_SUFFIXES, f"the file named by mesh '{mesh.name}',",
                                "material, texture or buffer")
    if refusal is None and roots is not None and not _is_under(os.path.realpath(path), roots):
        refusal = _outside(name, path, f"the file named by mesh '{mesh.name}'")
    return refusal


def _head(path: Path) -> bytes:
    with open(path, "rb") as f:  # the caller has checked it is a regular, bounded file
        return f.read(limits.in_bytes(limits.MESH))


def _obj_references(mesh: Path, roots: Iterable[str] | None) -> str | None:
    for line in _head(mesh).decode("latin-1").splitlines():
        words = line.split()
        if len(words) < 2 or words[0] != "mtllib":
            continue
        whole = line.strip()[len("mtllib"):].strip()  # readers split it at spaces, or take it whole
        for name in dict.fromkeys([whole, *words[1:]]):
            refusal = _reference_refusal(name, mesh, roots)
            if refusal:
                return refusal
            library = mesh.parent / name if not os.path.isabs(name) else Path(name)
            if not library.is_file():
                continue
            for entry in _head(library).decode("latin-1").splitlines():
                fields = entry.split()
                if len(fields) >= 2 and (fields[0].lower().startswith("map_") or fields[0].lower() in _MTL_MAPS):
                    refusal = _reference_refusal(fields[-1], library, roots)
                    if refusal:
                        return refusal
    return None


_MTL_MAPS = ("bump", "disp", "decal", "refl", "norm")


def _gltf_names(document: dict) -> list[str]:
    entries = list(document.get("buffers") or []) + list(document.get("images") or [])
    return [e["uri"] for e in entries if isinstance(e, dict) and isinstance(e.get("uri"), str)]


def _gltf_uris(mesh: Path) -> list[str]:
    document = json.loads(_head(mesh))
    return _gltf_names(document) if isinstance(document, dict) else []


def _glb_uris(mesh: Path) -> list[str]:
    data = _head(mesh)
    if len(data) < 20 or data[:4] != b"glTF":
        raise ValueError("not a binary glTF file")
    length, kind = struct.unpack_from("<II", data, 12)
    if kind != 0x4E4F534A:  # "JSON": the first chunk of every .glb
        raise ValueError("binary glTF without a JSON chunk")
    document = json.loads(data[20:20 + length])
    return _gltf_names(document) if isinstance(document, dict) else []


_DAE_IMAGE = re.compile(rb"<image\b.*?</image\s*>", re.S)
_INIT_FROM = re.compile(rb"<init_from\b[^>]*>\s*(?:<ref\b[^>]*>)?\s*([^<]*?)\s*<", re.S)


def _dae_images(mesh: Path) -> list[str]:
    names = []
    for image in _DAE_IMAGE.finditer(_head(mesh)):
        for match in _INIT_FROM.finditer(image.group(0)):
            names.append(decoded_character_references(match.group(1).decode("latin-1")))
    return names
