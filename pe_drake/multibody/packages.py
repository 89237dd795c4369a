"""Where ``package://<name>/...`` URIs point: one resolver for Drake's parser, xacro's
``$(find <name>)``, capsule fitting and the STL → OBJ visuals.

A package's folder is looked up, first match wins, in: the config's ``robot.packages`` map; the
folders above the model file (a ``package.xml`` naming the package, or a folder of that name;
Drake 1.51.1 has no upward search); ``ROS_PACKAGE_PATH``, searched downwards as ``rospack``
does; ``<prefix>/share/<name>`` of each ``AMENT_PREFIX_PATH`` prefix; example-robot-data.
"""

from __future__ import annotations

import contextlib
import os
import re
import sys
import sysconfig
from collections.abc import Iterator, Mapping
from functools import lru_cache
from pathlib import Path

from pe_drake.exceptions import ConfigError

#: Folder levels searched below each ``ROS_PACKAGE_PATH`` entry.
ROS_PACKAGE_PATH_DEPTH = 6

_PACKAGE_URI = re.compile(r"package://([^/\"'\s]+)/")
_NAME = re.compile(r"<name>\s*([^<\s]+)\s*</name>")


def example_robot_data_dir() -> Path:
    """The ``share/example-robot-data`` folder of the installed wheel; ConfigError without it."""
    for root in [sysconfig.get_paths()["purelib"], *sys.path]:
        candidate = Path(root) / "cmeel.prefix" / "share" / "example-robot-data"
        if candidate.is_dir():
            return candidate
    raise ConfigError(
        "the robot models of 'example-robot-data' are not installed: "
        "pip install example-robot-data")


def manifest_name(folder: Path) -> str | None:
    """The ``<name>`` of ``folder/package.xml``, or None without a readable manifest."""
    manifest = folder / "package.xml"
    if not manifest.is_file():
        return None
    try:
        match = _NAME.search(manifest.read_text(errors="replace"))
    except OSError:
        return None
    return match.group(1) if match else None


def package_roots(package: str, model_path: str | Path,
                  packages: Mapping[str, str] | None = None) -> list[Path]:
    """Existing candidate folders of a package, best first (module docstring); the upward
    search starts at ``model_path``, ``packages`` is the config's ``robot.packages``."""
    return list(dict.fromkeys(_candidates(package, Path(model_path), packages or {})))


def _candidates(package: str, model_path: Path, packages: Mapping[str, str]) -> Iterator[Path]:
    if package in packages:
        yield Path(packages[package]).expanduser().resolve()
    for folder in model_path.resolve().parents:
        if folder.name == package or manifest_name(folder) == package:
            yield folder
    for entry in _env_paths("ROS_PACKAGE_PATH"):
        found = _ros_package_path_index(str(entry)).get(package)
        if found is not None:
            yield Path(found)
    for prefix in _env_paths("AMENT_PREFIX_PATH"):
        share = prefix / "share" / package
        if share.is_dir():
            yield share.resolve()
    if package == "example-robot-data":
        with contextlib.suppress(ConfigError):
            yield example_robot_data_dir()


def find_package(package: str, model_path: str | Path, packages: Mapping[str, str] | None = None) -> Path:
    """The folder of a package (xacro's ``$(find <package>)``); ConfigError when unknown."""
    roots = package_roots(package, model_path, packages)
    if not roots:
        raise ConfigError(unknown_package_message(package, model_path))
    return roots[0]


def unknown_package_message(package: str, model_path: str | Path) -> str:
    """What to do about a package that none of the places knows."""
    return (
        f"package '{package}' (used by '{Path(model_path).name}') was not found: looked in robot.packages, "
        f"for a package.xml named '{package}' (or a folder of that name) above the model, in "
        "ROS_PACKAGE_PATH and in AMENT_PREFIX_PATH/share; set robot.packages: "
        f"{{{package}: /path/to/{package}}} in the config, or source the ROS workspace")


def resolve_package_uri(uri: str, model_path: str | Path, packages: Mapping[str, str] | None = None) -> Path | None:
    """The existing file of a ``package://<name>/<rest>`` URI, or None."""
    package, _, rest = uri[len("package://") :].lstrip("/").partition("/")  # TALOS writes package:///
    for root in package_roots(package, model_path, packages):
        if (root / rest).exists():
            return root / rest
    return None


def used_packages(text: str) -> list[str]:
    """Names of the packages a model's text refers to by ``package://`` URIs, in order."""
    return list(dict.fromkeys(_PACKAGE_URI.findall(text)))


def found_packages(text: str, model_path: str | Path, packages: Mapping[str, str] | None = None) -> dict[str, str]:
    """{name: folder} of every package the text uses that is found from ``model_path``: the
    ``robot.packages`` of an exported file, so its URIs resolve as the model's did."""
    found = {}
    for package in used_packages(text):
        roots = package_roots(package, model_path, packages)
        if roots:
            found[package] = str(roots[0])
    return found


def register_packages(package_map, text: str, model_path: str | Path, packages: Mapping[str, str] | None = None) -> list[str]:
    """Adds every package the text uses and Drake does not know to the parser's ``PackageMap``;
    returns those none of the places knows (left for Drake to report)."""
    unknown = []
    for package in used_packages(text):
        if package_map.Contains(package):
            continue
        roots = package_roots(package, model_path, packages)
        if roots:
            package_map.Add(package, str(roots[0]))
        else:
            unknown.append(package)
    return unknown


def _env_paths(variable: str) -> list[Path]:
    return [Path(p).expanduser() for p in os.environ.get(variable, "").split(os.pathsep) if p.strip()]


@lru_cache(maxsize=32)
def _ros_package_path_index(entry: str) -> dict[str, str]:
    """{package name: folder} below one ``ROS_PACKAGE_PATH`` entry (not below a package, nor
    into hidden folders or folders holding a ``CATKIN_IGNORE`` / ``COLCON_IGNORE``)."""
    found: dict[str, str] = {}

    def walk(folder: Path, depth: int) -> None:
        name = manifest_name(folder)
        if name is not None:
            found.setdefault(name, str(folder.resolve()))
            return
        if depth >= ROS_PACKAGE_PATH_DEPTH or (folder / "CATKIN_IGNORE").exists() or (folder / "COLCON_IGNORE").exists():
            return
        with contextlib.suppress(OSError):
            for child in sorted(folder.iterdir()):
                if child.is_dir() and not child.name.startswith("."):
                    walk(child, depth + 1)

    walk(Path(entry), 0)
    return found


def clear_cache() -> None:
    """Forgets the ``ROS_PACKAGE_PATH`` folders already searched (after packages move)."""
    _ros_package_path_index.cache_clear()
