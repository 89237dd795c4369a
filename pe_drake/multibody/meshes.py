"""Mesh reading (STL, OBJ, COLLADA), mesh-name resolution, and STL → OBJ visuals for Meshcat.

Drake's Meshcat draws .obj/.gltf/.dae visuals only, so :func:`stl_visuals_to_obj` rewrites a
URDF's ``<visual>`` STL meshes to OBJ files converted once into a cache folder.
"""

from __future__ import annotations

import hashlib
import os
import re
from pathlib import Path
from typing import NamedTuple

import numpy as np

from pe_drake.exceptions import DataError
from pe_drake.io_utils import atomic_write_text
from pe_drake.multibody.mesh_policy import mesh_file_refusal, without_refused_elements
from pe_drake.multibody.packages import package_roots

#: Environment variable naming the folder of converted meshes (overrides the default cache).
CACHE_ENV = "PE_DRAKE_MESH_CACHE"

_BINARY_DTYPE = np.dtype([("normal", "<f4", (3,)), ("vertices", "<f4", (3, 3)), ("attribute", "<u2")])
_VISUAL = re.compile(r"<visual\b.*?</visual\s*>", re.S)
# (?<![\w:.-]): the attribute itself, not data-filename= or x:filename= before it
_MESH_FILENAME = re.compile(r"(<mesh\b[^>]*?(?<![\w:.-])filename\s*=\s*)([\"'])(.*?)\2", re.S)
_FILE_NAME = re.compile(r"(<(?:mesh|texture)\b[^>]*?(?<![\w:.-])filename\s*=\s*)([\"'])(.*?)\2", re.S)
_FLOAT = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_ASCII_VERTEX = re.compile(
    rb"vertex\s+(" + _FLOAT.encode() + rb")\s+(" + _FLOAT.encode() + rb")\s+(" + _FLOAT.encode() + rb")"
)


class TriangleMesh(NamedTuple):
    """An indexed triangle mesh: vertices (V, 3) [model units], faces (F, 3) (counter-clockwise)."""

    vertices: np.ndarray
    faces: np.ndarray


def read_stl(path: str | Path) -> TriangleMesh:
    """Reads a binary or ASCII STL file, merging identical vertices and dropping degenerate faces.

    DataError for a missing file or one that is neither binary nor ASCII STL."""
    path = Path(path)
    return _index_corners(_stl_corners(_stl_bytes(path), path))


def _stl_bytes(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as err:
        raise DataError(f"cannot read STL file: {err}", file=str(path)) from err


def _stl_corners(data: bytes, path: Path) -> np.ndarray:
    """Triangle corners of an STL file, shape (F, 3, 3)."""
    if len(data) >= 84:
        count = int(np.frombuffer(data, "<u4", 1, 80)[0])
        if len(data) == 84 + 50 * count:
            facets = np.frombuffer(data, _BINARY_DTYPE, count, 84)
            return facets["vertices"].astype(float)
    # ASCII STL starts with "solid"; binary files may too, so the size test above comes first.
    if data.lstrip()[:5].lower() == b"solid":
        values = np.array(_ASCII_VERTEX.findall(data), float)
        if values.size == 0 and b"facet" in data:
            raise DataError("ASCII STL without readable 'vertex x y z' lines", file=str(path))
        if len(values) % 3:
            raise DataError(f"ASCII STL has {len(values)} vertices, not a multiple of 3", file=str(path))
        return values.reshape(-1, 3, 3)
    raise DataError(
        f"not an STL file: {len(data)} bytes, neither binary (84 + 50·n bytes) nor ASCII ('solid ...')",
        file=str(path),
    )


def _index_corners(corners: np.ndarray) -> TriangleMesh:
    if corners.size == 0:
        return TriangleMesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64))
    vertices, inverse = np.unique(corners.reshape(-1, 3), axis=0, return_inverse=True)
    faces = inverse.reshape(-1, 3)
    keep = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    return TriangleMesh(vertices, faces[keep])


def read_mesh_vertices(path: str | Path) -> np.ndarray:
    """Vertices of an STL, OBJ or COLLADA (.dae) mesh, shape (V, 3) [file units; DAE in m]."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".stl":
        return read_stl(path).vertices
    if suffix == ".obj":
        rows = []
        for line in path.read_text(errors="replace").splitlines():
            if line.startswith("v "):
                try:
                    rows.append([float(x) for x in line.split()[1:4]])
                except ValueError as err:
                    raise DataError(f"bad vertex line {line!r}", file=str(path)) from err
        if not rows:
            raise DataError("no vertices ('v x y z' lines)", file=str(path))
        return np.asarray(rows, float)
    if suffix == ".dae":
        return read_dae_vertices(path)
    raise DataError(f"mesh format '{suffix}' is not read for capsule fitting (STL, OBJ and DAE are)", file=str(path))


def _dae_primitives(path: Path) -> tuple[list, float]:
    """The bound primitives of a COLLADA file's scene (node transforms applied), metres per unit."""
    import collada  # lazy: only DAE meshes need it

    with open(path, "rb") as f:  # the caller checked it is a regular file of bounded size
        if b"<!ENTITY" in f.read().upper():
            # pycollada parses with lxml when it is installed, which expands external entities:
            # a file's content would reach the parse tree and its error messages.
            raise DataError("COLLADA file declares XML entities (<!ENTITY>), which pe_drake does not read", file=str(path))
    try:
        ignore = [collada.common.DaeUnsupportedError, collada.common.DaeBrokenRefError]
        mesh = collada.Collada(str(path), ignore=ignore)
        geometries = mesh.scene.objects("geometry") if mesh.scene is not None else ()
        primitives = [p for geometry in geometries for p in geometry.primitives()]
        return primitives, float(mesh.assetInfo.unitmeter or 1.0)
    except Exception as err:  # pycollada raises many types (XML, DaeError, KeyError, ...)
        raise DataError(f"cannot read COLLADA file: {type(err).__name__}: {err}", file=str(path)) from err


def read_dae_vertices(path: Path) -> np.ndarray:
    """Vertices of a COLLADA file's scene (node transforms applied), scaled to metres."""
    primitives, unit = _dae_primitives(path)
    blocks = [np.asarray(p.vertex, float).reshape(-1, 3) for p in primitives
              if p.vertex is not None and len(p.vertex)]
    if not blocks:
        raise DataError("COLLADA file has no geometry in its scene", file=str(path))
    return np.vstack(blocks) * unit


def obj_text(mesh: TriangleMesh, comment: str = "") -> str:
    """Wavefront OBJ text of a mesh: ``v`` lines (6 significant digits) and ``f`` lines."""
    v = np.asarray(mesh.vertices, float)
    f = np.asarray(mesh.faces, np.int64) + 1  # OBJ indices start at 1
    head = f"# {comment}\n" if comment else ""
    vertices = ("v %.6g %.6g %.6g\n" * len(v)) % tuple(v.ravel())
    return head + vertices + ("f %d %d %d\n" * len(f)) % tuple(f.ravel())


def write_obj(path: str | Path, mesh: TriangleMesh, comment: str = "") -> Path:
    """Writes a mesh as OBJ atomically and returns the path."""
    atomic_write_text(path, obj_text(mesh, comment))
    return Path(path)


def default_cache_dir() -> Path:
    """Folder of converted meshes: ``$PE_DRAKE_MESH_CACHE``, else the user cache folder."""
    if os.environ.get(CACHE_ENV):
        return Path(os.environ[CACHE_ENV]).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "pe_drake" / "meshes"


def stl_to_obj(stl_path: str | Path, cache_dir: str | Path | None = None) -> Path:
    """The OBJ conversion of an STL file, cached as ``<cache_dir>/<content hash>/<stem>.obj``."""
    stl_path = Path(stl_path)
    data = _stl_bytes(stl_path)
    digest = hashlib.blake2b(data, digest_size=8).hexdigest()
    target = Path(cache_dir or default_cache_dir()) / digest / f"{stl_path.stem}.obj"
    if not target.is_file():
        mesh = _index_corners(_stl_corners(data, stl_path))
        write_obj(target, mesh, comment=f"converted by pe_drake from {stl_path.name}")
    return target


def stl_visuals_to_obj(urdf_text: str, model_path: str | Path, cache_dir: str | Path | None = None,
                       packages: dict | None = None) -> str:
    """Rewrites the STL meshes of a URDF's ``<visual>`` elements to cached OBJ conversions.

    Only the ``filename`` of ``<mesh>`` inside ``<visual>`` changes, to a ``file://`` URI
    (Drake refuses bare absolute paths in a URDF parsed from a string); every ``<collision>``
    stays. Meshes that cannot be found are left untouched for Drake to report; a malformed STL
    raises DataError.
    """
    return rewrite_visual_meshes(urdf_text, model_path, ".stl", lambda source: stl_to_obj(source, cache_dir),
                                 packages)


def rewrite_visual_meshes(urdf_text: str, model_path: str | Path, suffix: str, convert,
                          packages: dict | None = None) -> str:
    """Rewrites the ``<visual>`` meshes named ``*suffix`` to ``convert(path)`` (a file:// URI)."""
    model_path = Path(model_path)
    converted: dict[str, str] = {}

    def mesh(match: re.Match) -> str:
        name = match.group(3)
        if not name.lower().endswith(suffix):
            return match.group(0)
        if name not in converted:
            source = resolve_mesh_path(name, model_path, packages)
            out = convert(source) if source is not None else None
            converted[name] = out.resolve().as_uri() if out is not None else name
        return f"{match.group(1)}{match.group(2)}{converted[name]}{match.group(2)}"

    return _VISUAL.sub(lambda visual: _MESH_FILENAME.sub(mesh, visual.group(0)), urdf_text)


def read_dae_triangles(path: Path) -> TriangleMesh:
    """The triangles of a COLLADA file's scene (node transforms applied), in metres."""
    primitives, unit = _dae_primitives(path)
    corners = []
    for primitive in primitives:
        try:
            tris = primitive.triangleset() if hasattr(primitive, "triangleset") else primitive
        except Exception as err:  # noqa: BLE001 (pycollada's many error types)
            raise DataError(f"cannot read COLLADA file: {type(err).__name__}: {err}", file=str(path)) from err
        index = np.asarray(getattr(tris, "vertex_index", []))
        # a line set (Panda's link meshes have them) has pairs, not triangles: it has no surface
        if getattr(tris, "vertex", None) is not None and len(index) and index.shape[-1] == 3:
            corners.append(np.asarray(tris.vertex, float)[index])
    if not corners:
        raise DataError("COLLADA file has no triangles in its scene", file=str(path))
    return _index_corners(np.concatenate(corners).reshape(-1, 3, 3) * unit)


def absolute_mesh_paths(urdf_text: str, model_path: str | Path) -> str:
    """Rewrites a URDF's relative and absolute mesh and texture names to ``file://`` URIs.

    Drake parses our rewritten text from a string, where a relative name has no folder to
    resolve against and a bare absolute path is refused. Other URIs are left as they are."""
    folder = Path(model_path).resolve().parent

    def absolute(match: re.Match) -> str:
        name = match.group(3)
        if "://" in name:
            return match.group(0)
        path = Path(name) if Path(name).is_absolute() else folder / name
        return f"{match.group(1)}{match.group(2)}{path.resolve().as_uri()}{match.group(2)}"

    return _FILE_NAME.sub(absolute, urdf_text)


def resolve_mesh_path(name: str, model_path: str | Path, packages: dict | None = None, *,
                      mesh: bool = True) -> Path | None:
    """The file a URDF mesh filename points to, or None when it does not exist.

    Args:
        name: the ``filename`` attribute (``package://``, ``file://``, absolute or relative).
        mesh: the file must pass :func:`~pe_drake.multibody.mesh_policy.mesh_file_refusal`
            (False to resolve a model file's own URI).
    """
    model_path = Path(model_path)
    if name.startswith("package://"):
        package, _, rest = name[len("package://") :].lstrip("/").partition("/")  # TALOS writes package:///
        for root in package_roots(package, model_path, packages):
            if _present(root / rest, mesh):
                return root / rest if not mesh or mesh_file_refusal(root / rest) is None else None
        return None
    if name.startswith("file://"):
        name = name[len("file://") :]
    path = Path(name)
    if not path.is_absolute():
        path = model_path.parent / path
    return path if _present(path, mesh) and (not mesh or mesh_file_refusal(path) is None) else None


def _present(path: Path, mesh: bool) -> bool:
    """A regular file; without ``mesh``, anything there (the caller refuses a pipe or a folder)."""
    return path.is_file() if mesh else os.path.lexists(path)


def without_refused_visuals(urdf_text: str, model_path: str | Path, roots,
                            packages: dict | None = None) -> tuple[str, list[str]]:
    """The URDF text without the ``<visual>`` elements whose mesh must not be read, and notes."""
    return without_refused_elements(urdf_text, _VISUAL, _MESH_FILENAME, 3, "visual", model_path, roots, packages)
