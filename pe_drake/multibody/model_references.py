"""The read policy (:mod:`pe_drake.multibody.mesh_policy`) applied to every file a model names
besides its URDF visual meshes: URDF material textures, SDF ``<uri>`` elements and MJCF
``file`` attributes.

A texture, SDF visual or collision whose file is refused is dropped with a note; an SDF
``<include>`` or an MJCF asset whose file is refused stops the load. Relative SDF URIs become
``file://`` URIs: Drake parses the checked text from a string.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable, Mapping
from pathlib import Path

from pe_drake.exceptions import ConfigError
from pe_drake.multibody.mesh_policy import (
    MESH_SUFFIXES,
    REFERENCE_SUFFIXES,
    is_under,
    mesh_file_refusal,
    name_refusal,
    named_files,
    visual_mesh_refusal,
    without_refused_elements,
)

_TEXTURE = re.compile(r"<texture\b[^>]*?(?<![\w:.-])filename\s*=\s*([\"'])(.*?)\1[^>]*?(?:/>|>.*?</texture\s*>)", re.S)
_MATERIAL = re.compile(r"(<material\b[^>]*?(?<!/)>)(.*?)(</material\s*>)", re.S)
# Every element Drake reads a file for in a URDF (a <gazebo> plugin's filename is not read)
_ANY_FILENAME = re.compile(r"(<(?:\w+:)?(?:mesh|texture)\b[^>]*?(?<![\w:.-])filename\s*=\s*)([\"'])(.*?)\2", re.S)
_SDF_GEOMETRY = re.compile(r"<(visual|collision)\b.*?</\1\s*>", re.S)
_SDF_URI = re.compile(r"(<uri\b[^>]*>)\s*(.*?)\s*(</uri\s*>)", re.S)
_SDF_INCLUDE = re.compile(r"<include\b")
_SDF_MAP = re.compile(r"(?=<([\w:]*_map)\b)(<[\w:]*_map\b[^>]*>)\s*(.*?)\s*(</[\w:]*_map\s*>)", re.S)
_MJCF_FILE = re.compile(r"(<(\w+)\b[^>]*?(?<![\w:.-])file\s*=\s*)([\"'])(.*?)\3", re.S)
_MJCF_DIR = re.compile(r"<compiler\b[^>]*?(?<![\w:.-])(meshdir|texturedir|assetdir)\s*=\s*([\"'])(.*?)\2", re.S)


def file_refusal(name: str, model_path: Path, roots: Iterable[str] | None, packages: Mapping[str, str] | None,
                 suffixes: tuple[str, ...], what: str) -> str | None:
    """Why the file a model names (``what``: "texture", ...) must not be read, or None."""
    refusal = name_refusal(name)
    if refusal is not None:
        return f"{what} {refusal}"
    for path in named_files(name, model_path, packages):
        if not os.path.lexists(path):
            continue  # a missing file: Drake names it
        refusal = mesh_file_refusal(path, suffixes, what, "texture" if suffixes == REFERENCE_SUFFIXES else "model")
        if refusal is None and roots is not None and not is_under(path, roots):
            refusal = (f"{what} '{name}' is {os.path.realpath(path)}, outside the model's folder, its packages and "
                       "pe_drake's mesh cache: files are read only from there")
        if refusal:
            return refusal
    return None


def without_refused_textures(text: str, model_path: str | Path, roots: Iterable[str] | None,
                             packages: Mapping[str, str] | None = None) -> tuple[str, list[str]]:
    """URDF text without the ``<texture>`` elements whose image must not be read, and notes.

    A material left with neither colour nor texture gets a white one (Drake refuses it empty)."""
    notes: list[str] = []

    def texture(match: re.Match) -> str:
        refusal = file_refusal(match.group(2), Path(model_path), roots, packages, REFERENCE_SUFFIXES, "texture")
        if refusal is None:
            return match.group(0)
        notes.append(f"texture dropped: {refusal}")
        return ""

    def material(match: re.Match) -> str:
        body = _TEXTURE.sub(texture, match.group(2))
        if body != match.group(2) and not re.search(r"<(color|texture)\b", body):
            body += '<color rgba="1 1 1 1"/>'
        return match.group(1) + body + match.group(3)

    return _MATERIAL.sub(material, text), notes


def check_every_name(text: str, model_path: str | Path, roots: Iterable[str] | None,
                     packages: Mapping[str, str] | None = None) -> None:
    """Refuses (ConfigError) a model text in which any mesh or texture name or ``<uri>`` left
    fails the read policy: the last check before Drake parses it."""
    model_path = Path(model_path)
    names = [m.group(3) for m in _ANY_FILENAME.finditer(text)] + [m.group(2) for m in _SDF_URI.finditer(text)]
    for name in names:
        texture = Path(name.split("?")[0]).suffix.lower() in REFERENCE_SUFFIXES
        refusal = (file_refusal(name, model_path, roots, packages, REFERENCE_SUFFIXES, "texture") if texture
                   else visual_mesh_refusal(name, model_path, roots, packages))
        if refusal is not None:
            raise ConfigError(f"'{model_path}': {refusal}")


def checked_sdf_text(text: str, model_path: str | Path, roots: Iterable[str] | None,
                     packages: Mapping[str, str] | None = None) -> tuple[str, list[str]]:
    """SDF text with relative ``<uri>`` names made absolute and refused visuals and collisions
    dropped (a note each); ConfigError for an ``<include>``."""
    model_path = Path(model_path)
    text, notes = without_refused_elements(text, _SDF_GEOMETRY, _SDF_URI, 2, None, model_path, roots, packages)
    if _SDF_INCLUDE.search(text):
        raise ConfigError(f"'{model_path}' <include>s another model: Drake would read that file without "
                          "pe_drake's checks of the files a model names; write the included model into this file")
    text = _SDF_MAP.sub(lambda m: _checked_map(m, model_path, roots, packages, notes), text)
    return _SDF_URI.sub(lambda m: m.group(1) + _absolute(m.group(2), model_path, packages) + m.group(3), text), notes


def _checked_map(match: re.Match, model_path: Path, roots, packages, notes: list[str]) -> str:
    refusal = file_refusal(match.group(3), model_path, roots, packages, REFERENCE_SUFFIXES, f"<{match.group(1)}>")
    if refusal is not None:
        notes.append(f"texture dropped: {refusal}")
        return ""
    return match.group(2) + _absolute(match.group(3), model_path, packages) + match.group(4)


def _absolute(name: str, model_path: Path, packages: Mapping[str, str] | None) -> str:
    """The checked file of a name as a ``file://`` URI, or the name itself when there is none."""
    found = [p for p in named_files(name, model_path, packages) if os.path.lexists(p)]
    return found[0].resolve().as_uri() if name and found else name


def check_mjcf_files(text: str, model_path: str | Path, roots: Iterable[str] | None) -> None:
    """Refuses (ConfigError) an MJCF model any of whose ``file`` attributes the policy refuses."""
    model_path = Path(model_path)
    folders = {kind: value for kind, _, value in _MJCF_DIR.findall(text)}
    for match in _MJCF_FILE.finditer(text):
        element, name = match.group(2), match.group(4)
        kind = "texturedir" if element in ("texture", "hfield") else "meshdir"
        base = folders.get(kind) or folders.get("assetdir") or ""
        path = Path(name) if os.path.isabs(name) else model_path.parent / base / name
        refusal = file_refusal(str(path), model_path, roots, None, (*MESH_SUFFIXES, *REFERENCE_SUFFIXES, ".xml"),
                               f"<{element} file>")
        if refusal is not None:
            raise ConfigError(f"'{model_path}': {refusal}")
