"""Lazy re-exports (PEP 562) for the package and its stages.

A package lists ``{name: module}``; a name's module is imported on its first use, so importing
a stage loads none of its siblings (``pe-drake optimize`` loads no identification module) and
``import pe_drake`` does not load pydrake.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any


def lazy_exports(package: str, exports: dict[str, str]) -> Callable[[str], Any]:
    """The module-level ``__getattr__`` of ``package`` that imports ``exports[name]`` on first use."""

    def __getattr__(name: str) -> Any:
        if name in exports:
            return getattr(importlib.import_module(exports[name]), name)
        raise AttributeError(f"module '{package}' has no attribute '{name}'")

    return __getattr__


def exports_by_module(package: str, table: dict[str, str]) -> dict[str, str]:
    """``{name: module}`` of ``{submodule of package: "name name ..."}``."""
    return {name: f"{package}.{module}" for module, names in table.items() for name in names.split()}
