"""What the diagnosis returns and writes: :class:`NamedEffect` and :class:`DiagnosisResult`, whose
:meth:`~DiagnosisResult.write` writes diagnosis.json, report.md, the figures and the augmented
model files."""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pe_drake.diagnosis.augmented_model import write_augmented_model
from pe_drake.diagnosis.options import DiagnosisConfig
from pe_drake.diagnosis.record import Segment
from pe_drake.diagnosis.report import write_report
from pe_drake.identification.reference_errors import Shortfall, shortfall_report
from pe_drake.io_utils import atomic_write_text, staged_output_dir
from pe_drake.multibody.robot import Robot
from pe_drake.multibody.robot_model import RobotModel
from pe_drake.output_paths import DIAGNOSE_OUTPUTS, check_output_dir


def per_joint(joints: Sequence[str], x) -> dict[str, float]:
    """{joint: value} of a per-joint array."""
    return {j: float(v) for j, v in zip(joints, x)}


def time_delay_effect(value: float, std: float, contribution_rms: dict[str, float], before: dict[str, float],
                      after: dict[str, float]) -> NamedEffect:
    """The named ``time_delay``: d [s] of τ_rec(t) = τ(t − d) (positive: the torque log lags);
    ``contribution_rms``: held-out RMS of the −d·dτ/dt term per joint [N·m]."""
    details = {"convention": "tau_recorded(t) = tau(t - time_delay): positive when the torque log lags "
                             "the positions",
               "contribution_rms": contribution_rms,
               "note": "a logging offset between the torque and position streams, not a physical effect: "
                       "fix the logging, or keep it in the model (augmented_effects.yaml torque_delay)"}
    return NamedEffect("time_delay", "", "", float(value), "s", float(std), float(abs(value) / max(std, 1e-300)),
                       before, after, details)


@dataclasses.dataclass(frozen=True)
class NamedEffect:
    """An effect the diagnosis names.

    Attributes:
        joint, link: the joint (per-joint effects) or the link (payload), the other "".
        value: identified value in ``unit`` (payload: the added mass).
        z: |value| / std of the fitted increment (per-joint effects) or the mass (payload).
        heldout_rms_before, heldout_rms_after: per-joint held-out RMS before and after the
            effect was added [N·m].
        details: effect-specific extras (payload centre of mass, welded bodies, χ² values).
    """

    effect: str
    joint: str
    link: str
    value: float
    unit: str
    std: float
    z: float
    heldout_rms_before: dict[str, float]
    heldout_rms_after: dict[str, float]
    details: dict[str, Any]

    def as_dict(self) -> dict[str, Any]:
        """The effect's entry in diagnosis.json."""
        out = {"effect": self.effect}
        if self.joint:
            out["joint"] = self.joint
        if self.link:
            out["link"] = self.link
        out.update(value=self.value, unit=self.unit, std=self.std, z=self.z,
                   heldout_rms_before=self.heldout_rms_before, heldout_rms_after=self.heldout_rms_after,
                   **self.details)
        return out


@dataclasses.dataclass(frozen=True, eq=False)
class DiagnosisResult:
    """Everything the diagnosis found (JSON via :meth:`to_json_dict`; files via :meth:`write`).

    Attributes:
        effects: the :class:`NamedEffect`s, in the order they were selected (payload last).
        rms_nominal, rms_rigid, rms_after: per-joint held-out RMS [N·m] of the a-priori model,
            after rigid-body re-identification, and of the augmented Drake model.
        cumulative: [(step label, per-joint held-out RMS)] nominal → rigid → each effect.
        rejected: every candidate tried and not named, with its statistic z and the reason
            (strongest first).
        predictions: held-out torques {"measured", "nominal", "rigid", "after"}, each (S, n).
        drake_check: max |Drake augmented torque - least-squares prediction| per joint [N·m].
        noise_floor: filtered white-noise level of the held-out torque per joint [N·m].
        thresholds: held-out residual RMS above which a joint is unexplained [N·m].
        worse: the joints whose augmented model is worse on the held-out part than the model
            file's, than predicting zero or than the starting fit, each with its reason.
    """

    robot: Robot
    joints: tuple[str, ...]
    config: DiagnosisConfig
    training: Segment
    held_out: Segment
    effects: list[NamedEffect]
    rms_nominal: np.ndarray
    rms_rigid: np.ndarray
    rms_after: np.ndarray
    cumulative: list[tuple[str, np.ndarray]]
    unexplained: dict[str, dict[str, Any]]
    not_separable: list[dict[str, Any]]
    rejected: list[dict[str, Any]]
    regimes: dict[str, Any]
    rigid: dict[str, Any]
    payload_test: dict[str, Any]
    timing: dict[str, Any]
    predictions: dict[str, np.ndarray]
    residual_series: dict[str, Any]
    augmented: RobotModel
    drake_check: np.ndarray
    timings: dict[str, float]
    noise_floor: np.ndarray
    thresholds: np.ndarray
    decisions: list[dict[str, Any]] = dataclasses.field(default_factory=list)
    selection: dict[str, Any] = dataclasses.field(default_factory=dict)
    holding_test: dict[str, Any] = dataclasses.field(default_factory=dict)
    worse: tuple[Shortfall, ...] = ()
    start: dict[str, Any] = dataclasses.field(default_factory=dict)

    def per_joint(self, x: np.ndarray) -> dict[str, float]:
        return per_joint(self.joints, x)

    def summary_lines(self) -> list[str]:
        """The held-out RMS nominal → augmented, the effects named and what is left."""
        def rms(x) -> str:
            return ", ".join(f"{j} {v:.3g}" for j, v in self.per_joint(x).items())

        named = ", ".join(f"{e.effect}[{e.joint or e.link}] {e.value:+.3g} {e.unit}" for e in self.effects)
        return [f"a-priori model, held-out RMS: {rms(self.rms_nominal)}",
                f"augmented model, held-out RMS: {rms(self.rms_after)}",
                f"named: {named or 'nothing'}",
                "unexplained: " + (", ".join(self.unexplained) or "nothing")] + [s.line() for s in self.worse]

    def write(self, folder: str | Path) -> list[str]:
        """Writes diagnosis.json, report.md, the figures and the augmented model files into
        ``folder``, all or nothing (staged, then moved into place); returns the paths written."""
        out = check_output_dir(folder)
        with staged_output_dir(out, "diagnosis.json", DIAGNOSE_OUTPUTS) as tmp:
            written = self._write_files(tmp)
        return [str(out / path.name) for path in written]

    def _write_files(self, folder: Path) -> list[Path]:
        model_files = write_augmented_model(folder, self.robot, self.augmented)
        figures = write_report(folder, self, model_files)
        data = self.to_json_dict()
        data["model_files"] = [Path(p).name for p in model_files]
        data["figures"] = [Path(p).name for p in figures]
        atomic_write_text(folder / "diagnosis.json", json.dumps(_jsonable(data), indent=2) + "\n")
        return [folder / "diagnosis.json", folder / "report.md", *figures, *model_files]

    def to_json_dict(self) -> dict[str, Any]:
        """The content of diagnosis.json."""
        rec_tr, rec_ho = self.training.record, self.held_out.record
        return {
            "robot": self.robot.name, "joints": list(self.joints),
            "units": {"torque": "N·m (N for prismatic joints)", "rms": "N·m"},
            "data": {"training": _segment_info(self.training),
                     "held_out": _segment_info(self.held_out),
                     "validation_file": rec_ho.source if rec_ho is not rec_tr else None,
                     "cutoff_hz": rec_tr.cutoff_hz, "full_rate_hz": rec_tr.rate_hz,
                     "fitted_rate_hz": rec_tr.rate_hz / rec_tr.step},
            "effects": [e.as_dict() for e in self.effects],
            "rms_nominal": self.per_joint(self.rms_nominal),
            "rms_rigid": self.per_joint(self.rms_rigid),
            "rms_after": self.per_joint(self.rms_after),
            "gap_closed": {j: _closed(a, b, c) for j, a, b, c
                           in zip(self.joints, self.rms_nominal, self.rms_rigid, self.rms_after)},
            "cumulative": [{"step": s, "rms": self.per_joint(r)} for s, r in self.cumulative],
            "unexplained": self.unexplained, "noise_floor": self.per_joint(self.noise_floor),
            "unexplained_threshold": self.per_joint(self.thresholds),
            "not_separable": self.not_separable,
            "rejected": self.rejected, "decisions": self.decisions, "selection": self.selection,
            "regimes": self.regimes, "rigid": self.rigid, "payload_test": self.payload_test,
            "timing": self.timing, "holding_test": self.holding_test, "starting_fit": self.start,
            "worse_than_references": shortfall_report(self.worse, ("a_priori", "zero", "start")),
            "drake_check_max_abs": self.per_joint(self.drake_check),
            "config": {k: (list(v) if isinstance(v, tuple) else v)
                       for k, v in dataclasses.asdict(self.config).items()},
            "timings_s": self.timings,
        }


def _closed(nominal: float, rigid: float, after: float) -> dict[str, float]:
    """Fractions of the nominal held-out mean-square gap closed by each stage."""
    if nominal <= 0:
        return {"rigid": 0.0, "total": 0.0}
    return {"rigid": float(1 - (rigid / nominal) ** 2), "total": float(1 - (after / nominal) ** 2)}


def _segment_info(seg: Segment) -> dict[str, Any]:
    return {"file": seg.record.source, "t_start": float(seg.t[0]), "t_end": float(seg.t[-1]),
            "samples": seg.num_samples}


def _jsonable(x):
    """``x`` with numpy scalars and arrays as Python values, non-finite floats as None."""
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x
