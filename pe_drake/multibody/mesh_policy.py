"""Which mesh files pe_drake and Drake may read: a model written by someone else must not copy
an arbitrary file into ``playback.html`` (Meshcat embeds every visual mesh whole), nor hang a run
on a named pipe or read ``/dev/zero`` until memory runs out.

A mesh is read only if its real path is a regular file with a mesh suffix, within
:data:`pe_drake.limits.MESH`, and, for a model's visuals, lies under the model's folder, a
package the model uses, pe_drake's mesh cache or example-robot-data. The files a mesh names
itself (materials, textures, buffers) pass the same checks: Meshcat embeds them too.
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

_CHARACTER_REFERENCE = re.compile(r"&#(?:[xX]([0-9a-fA-F]{1,8})|([0-9]{1,10}));")
_KEPT_ESCAPED = {"<": "&lt;", "&": "&amp;", '"': "&quot;", "'": "&apos;", ">": "&gt;"}


def decoded_character_references(text: str) -> str:
    """XML text with its numeric character references (``&#46;``) decoded, as the parser reads it.

    Markup characters and control characters stay escaped."""

    def one(match: re.Match) -> str:
        code = int(match.group(1), 16) if match.group(1) else int(match.group(2))
        if code < 0x20 or code > 0x10FFFF or 0xD800 <= code <= 0xDFFF:
            return match.group(0)
        char = chr(code)
        return _KEPT_ESCAPED.get(char, char)

    return _CHARACTER_REFERENCE.sub(one, text)


def mesh_file_refusal(path: str | Path, suffixes: tuple[str, ...] = MESH_SUFFIXES, what: str = "mesh",
                      kind: str | None = None) -> str | None:
    """Why the file ``path`` must not be read (a sentence naming it and the rule), or None."""
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


def allowed_mesh_roots(model_path: str | Path, text: str, packages: Mapping[str, str] | None,
                       extra: Iterable[str | Path] = ()) -> list[str]:
    """The real paths under which a model's visual meshes may lie: its folder, the roots of the
    packages its text uses (as found and as real paths) and ``extra`` folders."""
    roots = [Path(model_path).resolve().parent, *map(Path, extra)]
    for name in used_packages(text):
        roots += package_roots(name, model_path, packages)
    out = []
    for root in roots:
        out += [os.path.abspath(root), os.path.realpath(root)]
    return sorted(set(out))


def is_under(path: str | Path, roots: Iterable[str]) -> bool:
    """Whether the real path of ``path`` lies under one of the folders ``roots`` (real paths)."""
    real = os.path.realpath(path)
    return any(real == r or real.startswith(r.rstrip(os.sep) + os.sep) for r in roots)


_SCHEME = re.compile(r"^([A-Za-z][A-Za-z0-9+.-]*):")


def spellings(name: str) -> list[str]:
    """A file name as written and percent-decoded (a URI reader may decode ``%2E``)."""
    return list(dict.fromkeys((name, unquote(name))))


def name_refusal(name: str) -> str | None:
    """Why a file name a model gives must not be followed whatever it resolves to, or None.

    Refused: a scheme other than ``package://``, ``model://`` and local ``file://``, or a package
    path that climbs above its package's root, as written or percent-decoded."""
    for spelling in spellings(name):
        match = _SCHEME.match(spelling)
        scheme = match.group(1).lower() if match and len(match.group(1)) > 1 else ""  # "C:" is a drive
        if not scheme:
            continue
        if scheme not in ("package", "model", "file") or not spelling[len(scheme) + 1:].startswith("//"):
            return f"'{name}' is a {scheme}: URI: only package://, model://, file:// and paths are read"
        rest = spelling[len(scheme) + 3:]
        if scheme == "file":
            host = rest.split("/", 1)[0]
            if host not in ("", "localhost"):
                return f"'{name}' names host '{host}': only local files are read"
            continue
        inside = rest.lstrip("/").partition("/")[2]
        normal = os.path.normpath(inside) if inside else ""
        if os.path.isabs(inside) or normal == ".." or normal.startswith(".." + os.sep) or "\\" in inside:
            return f"'{name}' leaves its package's folder: a package:// name is read only inside its package"
    return None


def named_files(name: str, model_path: Path, packages: Mapping[str, str] | None) -> list[Path]:
    """The files a model's file name may be read as, one per spelling (:func:`spellings`)."""
    out = []
    for spelling in spellings(name):
        match = _SCHEME.match(spelling)
        scheme = match.group(1).lower() if match and len(match.group(1)) > 1 else ""
        if scheme in ("package", "model"):
            found = resolve_package_uri("package://" + spelling.split("://", 1)[1], model_path, packages)
            out += [found] if found is not None else []
            continue
        if scheme == "file":
            spelling = spelling[len("file://"):]
            spelling = spelling[len("localhost"):] if spelling.startswith("localhost/") else spelling
        path = Path(spelling)
        out.append(path if path.is_absolute() else model_path.parent / path)
    return out


def visual_mesh_refusal(name: str, model_path: str | Path, roots: Iterable[str] | None,
                        packages: Mapping[str, str] | None = None) -> str | None:
    """Why a visual mesh ``filename`` of a model must not be read, or None.

    ``roots``: :func:`allowed_mesh_roots`, or None to check only the file itself."""
    refusal = name_refusal(name)
    if refusal is not None:
        return refusal
    for path in named_files(name, Path(model_path), packages):
        if not os.path.lexists(path):
            continue  # a missing mesh: Drake names it
        refusal = mesh_file_refusal(path)
        if refusal is None and roots is not None and not is_under(path, roots):
            refusal = _outside(name, path)
        refusal = refusal or referenced_file_refusal(Path(path), roots)
        if refusal:
            return refusal
    return None


def _outside(name: str, path: str | Path, what: str = "mesh") -> str:
    return (f"{what} '{name}' is {os.path.realpath(path)}, outside the model's folder, its packages and "
            "pe_drake's mesh cache: meshes and the files they name are read only from there")


def referenced_file_refusal(mesh: Path, roots: Iterable[str] | None) -> str | None:
    """Why a file that the mesh ``mesh`` names must not be read, or None.

    Remembered per file version and roots: a model's meshes are checked twice per load."""
    roots = tuple(roots) if roots is not None else None
    try:
        info = os.stat(mesh)
    except OSError:
        return None
    key = (os.path.realpath(mesh), info.st_mtime_ns, info.st_size, roots)
    if key not in _CHECKED:
        if len(_CHECKED) > 4096:
            _CHECKED.clear()
        _CHECKED[key] = _referenced_file_refusal(mesh, roots)
    return _CHECKED[key]


_CHECKED: dict[tuple, str | None] = {}


def _referenced_file_refusal(mesh: Path, roots: tuple[str, ...] | None) -> str | None:
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
    """Checks a name a mesh gives, in each spelling a reader may follow (:func:`named_files`)."""
    if name.startswith("data:"):
        return None  # embedded in the mesh file itself
    refusal = name_refusal(name)
    if refusal is None and _SCHEME.match(name) and not name.lower().startswith("file:"):
        refusal = f"mesh '{mesh}' names '{name}': only files beside the mesh are read"
    if refusal is not None:
        return refusal
    for path in named_files(name, mesh, None):  # relative names are relative to the mesh's folder
        if not os.path.lexists(path):
            continue  # a missing texture: drawn without it
        refusal = mesh_file_refusal(path, REFERENCE_SUFFIXES, f"the file named by mesh '{mesh.name}',",
                                    "material, texture or buffer")
        if refusal is None and roots is not None and not is_under(path, roots):
            refusal = _outside(name, path, f"the file named by mesh '{mesh.name}'")
        if refusal:
            return refusal
    return None


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
                    # the last word (after options such as -s 1 1 1), or all after the keyword
                    # (a name with spaces), as readers differ
                    for image in dict.fromkeys([fields[-1], entry.strip().split(None, 1)[1]]):
                        refusal = _reference_refusal(image, library, roots)
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


def without_refused_elements(text: str, elements: re.Pattern, names: re.Pattern, group: int, label: str | None,
                             model_path, roots, packages=None) -> tuple[str, list[str]]:
    """``text`` without each element naming a file :func:`visual_mesh_refusal` refuses, and notes.

    The file name is group ``group`` of a ``names`` match inside the element; the note says
    "<label> dropped: <why>" (``label`` None: the element match's group 1, its tag)."""
    notes: list[str] = []

    def element(match: re.Match) -> str:
        for name in names.finditer(match.group(0)):
            refusal = visual_mesh_refusal(name.group(group), model_path, roots, packages)
            if refusal is not None:
                notes.append(f"{label or match.group(1)} dropped: {refusal}")
                return ""
        return match.group(0)

    return elements.sub(element, text), notes

