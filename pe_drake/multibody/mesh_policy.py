"""Which mesh files pe_drake and Drake may read: a model written by someone else must not copy
an arbitrary file into ``playback.html`` (Meshcat embeds every visual mesh whole), nor hang a run
on a named pipe or read ``/dev/zero`` until memory runs out.

A mesh is read only if its real path (symlinks resolved) is a regular file with a mesh suffix,
at most :data:`MAX_MESH_BYTES`, and, for a model's visuals, lies under the model's folder, the
root of a package the model uses (and that root's real path, for colcon ``--symlink-install``),
pe_drake's mesh cache or example-robot-data.
"""

from __future__ import annotations

import os
import stat
from collections.abc import Iterable, Mapping
from pathlib import Path

from pe_drake import limits
from pe_drake.multibody.packages import package_roots, resolve_package_uri, used_packages

#: Suffixes of the mesh formats pe_drake or Drake read.
MESH_SUFFIXES = (".stl", ".obj", ".dae", ".gltf", ".glb", ".ply", ".vtk")
#: Largest mesh file read [bytes] by default (:data:`pe_drake.limits.MESH` overrides it).
MAX_MESH_BYTES = 256 * 2**20


def mesh_file_refusal(path: str | Path) -> str | None:
    """Why the mesh file ``path`` must not be read (a sentence naming the path and the rule),
    or None when it may."""
    real = os.path.realpath(path)
    shown = f"'{path}'" + (f" (-> {real})" if real != os.path.abspath(path) else "")
    if Path(real).suffix.lower() not in MESH_SUFFIXES:
        return f"mesh {shown} is not a mesh file: only {', '.join(MESH_SUFFIXES)} files are read"
    try:
        info = os.stat(real)
    except OSError as err:
        return f"mesh {shown} cannot be read: {err.strerror}"
    if not stat.S_ISREG(info.st_mode):
        return f"mesh {shown} is not a regular file (a pipe, a device or a folder): only regular files are read"
    if info.st_size > limits.in_bytes(limits.MESH):
        return f"mesh {shown} has {info.st_size / 2**20:.0f} MB, over {limits.describe(limits.MESH)}"
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


def _mesh_file(name: str, model_path: Path, packages: Mapping[str, str] | None) -> Path | None:
    if name.startswith("package://"):
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
    path = _mesh_file(name, Path(model_path), packages)
    if path is None or not os.path.lexists(path):
        return None  # a missing mesh: Drake names it
    refusal = mesh_file_refusal(path)
    if refusal is None and roots is not None and not _is_under(os.path.realpath(path), roots):
        refusal = (f"mesh '{name}' is {os.path.realpath(path)}, outside the model's folder, its packages and "
                   "pe_drake's mesh cache: meshes are read only from there")
    return refusal
