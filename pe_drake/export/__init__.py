"""The identified robot where it is used: MJCF for MuJoCo, URDF/SDFormat for Drake and ROS,
controller feed-forward, PD gains and randomization ranges (``pe-drake export``), and
``validate --model`` of such a file in its simulator.

Its names load on first use, so ``pe-drake validate`` with an identified.json does not import
the exporters (nor the diagnosis they draw randomization projections from).
"""

from __future__ import annotations

import importlib

_NAMES = {
    "FORMATS": "pe_drake.export.model_export",
    "ExportOptions": "pe_drake.export.model_export",
    "ExportResult": "pe_drake.export.model_export",
    "export_model": "pe_drake.export.model_export",
    "IdentifiedSpread": "pe_drake.export.model_source",
    "exported_model": "pe_drake.export.model_source",
    "identified_spread": "pe_drake.export.model_source",
    "is_simulator_model": "pe_drake.export.simulator_validation",
    "validate_exported": "pe_drake.export.simulator_validation",
}

__all__ = sorted(_NAMES)


def __getattr__(name: str):
    if name in _NAMES:
        return getattr(importlib.import_module(_NAMES[name]), name)
    raise AttributeError(f"module 'pe_drake.export' has no attribute '{name}'")
