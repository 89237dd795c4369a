"""Options of the diagnosis and the thresholds derived from them and from the data.

:class:`DiagnosisConfig` holds what the user chooses (defaults are what
:mod:`pe_drake.diagnosis.workflow` describes); :class:`Thresholds` holds what the selection
and the ``unexplained`` step compare against once the noise floor and the torque spread are
known (of the training data for the selection, of the held-out data for ``unexplained``:
:func:`pe_drake.diagnosis.selection.selection_thresholds`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from pe_drake.diagnosis.effects import JOINT_EFFECTS, PRIOR_RELATIVE_UNCERTAINTY
from pe_drake.exceptions import ConfigError, UnknownNameError
from pe_drake.identification.gaps import MAX_GAP_S
from pe_drake.multibody.drive_columns import COULOMB_VELOCITY_SCALE

#: The effect (and column -dτ/dt) of a timing offset between the torque and position logs.
TIMING = "time_delay"
#: The decision of a starting-fit drive term kept in the model but not named (diagnosis/decisions.py).
KEPT = "kept, not named"
#: Largest condition number of the (column-scaled) training regressor the diagnosis accepts
#: (optimized trajectories give about 10).
MAX_COND = 1e4
#: Shortest part (training or held-out), in periods of the cut-off frequency: about 2 × this
#: many independent samples of filtered noise.
MIN_PERIODS = 10.0


#: The range of each numeric :class:`DiagnosisConfig` option: (field [unit], lower, upper).
_RANGES = (
    ("holdout_fraction", 0.05, 0.8), ("cutoff_hz [Hz]", 1e-3, 1e6), ("decimate_to_hz [Hz]", 1.0, 1e6),
    ("coulomb_velocity_scale [rad/s]", 1e-6, 10.0), ("alpha", 1e-12, 0.5), ("min_heldout_gain", 0.0, 0.9),
    ("min_effect_fraction", 0.0, 1.0), ("noise_factor", 0.0, 100.0), ("unexplained_fraction", 0.0, 1.0),
    ("resolution_fraction", 0.0, 0.1), ("prior_uncertainty", 1e-3, 0.5), ("payload_alpha", 1e-15, 0.5),
    ("payload_min_prior_sigmas", 0.0, 100.0), ("max_effects", 0, 1000), ("max_gap_s [s]", 0.0, 1e6),
)


@dataclasses.dataclass(frozen=True)
class DiagnosisConfig:
    """Options of the diagnosis (defaults are what the workflow's module docstring describes).

    Attributes:
        holdout_fraction: fraction of the record held out at its end when no validation file
            is given.
        cutoff_hz: low-pass cut-off [Hz]; None: from the data's spectrum (preprocess).
        timing_check: use the timing-offset nuisance column.
        alpha: family-wise probability of naming an effect that is not there.
        min_heldout_gain: relative RMS reduction an effect must bring on its joint, on data
            its fit has not seen: the training part's cross-validation (the name is older).
        min_effect_fraction: the torque an effect explains (cross-validated RMS) must reach
            this fraction of its joint's torque spread (std, training part).
        noise_factor: multiples of the noise floor for relevance and for ``unexplained``.
        unexplained_fraction: a joint is unexplained when its held-out residual RMS exceeds
            this fraction of its torque spread (and ``noise_factor`` × its noise floor).
        resolution_fraction: torque resolution as a fraction of the largest joint's torque
            spread (1e-4: a 14-bit sensor); no joint is held to less, neither for relevance
            nor for ``unexplained`` (noise-free simulated data have no noise floor).
        prior_uncertainty: relative a-priori uncertainty of the inertial parameters.
        payload_alpha: false-alarm probability of the payload test.
        payload_min_prior_sigmas: a payload's mass must exceed this many a-priori standard
            deviations of its link's mass.
        max_gap_s: holes in the time column up to this are interpolated [s]; a run paused for
            longer is diagnosed on its longest segment.
    """

    holdout_fraction: float = 0.3
    cutoff_hz: float | None = None  # [Hz]
    decimate_to_hz: float = 200.0  # [Hz]
    coulomb_velocity_scale: float = COULOMB_VELOCITY_SCALE  # [rad/s]
    effects: tuple[str, ...] = JOINT_EFFECTS
    payload: bool = True
    timing_check: bool = True
    alpha: float = 1e-3
    min_heldout_gain: float = 0.03
    min_effect_fraction: float = 0.001
    noise_factor: float = 3.0
    unexplained_fraction: float = 0.005
    resolution_fraction: float = 1e-4
    prior_uncertainty: float = PRIOR_RELATIVE_UNCERTAINTY
    payload_alpha: float = 1e-6
    payload_min_prior_sigmas: float = 3.0
    max_effects: int = 40
    max_gap_s: float = MAX_GAP_S  # [s]

    def __post_init__(self) -> None:
        def check(name, value, lo, hi):
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ConfigError(f"diagnosis option {name} must be a number, got {value!r}")
            if not lo <= value <= hi:
                raise ConfigError(f"diagnosis option {name} = {value} is outside [{lo}, {hi}]")

        for field, lo, hi in _RANGES:
            value = getattr(self, field.split(" ")[0])
            if value is not None or field != "cutoff_hz [Hz]":  # None: the cut-off from the data
                check(field, value, lo, hi)
        for e in self.effects:
            if e not in JOINT_EFFECTS:
                raise UnknownNameError("effect", e, JOINT_EFFECTS, where="diagnosis effects")


@dataclasses.dataclass(frozen=True, eq=False)
class Thresholds:
    """What a named effect and an explained joint are held to (criteria (b)-(d), step 5).

    Attributes:
        z_min: two-sided Bonferroni bound of the significance test, |θ| / σ_θ ≥ z_min.
        relevance: cross-validated RMS an effect must explain on its joint, (n,) [N·m].
        unexplained: held-out residual RMS above which a joint is unexplained, (n,) [N·m].
    """

    z_min: float
    min_heldout_gain: float
    relevance: np.ndarray
    unexplained: np.ndarray

    @classmethod
    def from_data(cls, config: DiagnosisConfig, noise_floor: np.ndarray, spread: np.ndarray,
                  num_tests: int) -> Thresholds:
        """The thresholds from the noise floor and torque spread per joint, (n,) [N·m], and the
        number of candidate columns tested (Bonferroni)."""
        n = len(spread)
        resolution = config.resolution_fraction * float(np.max(spread))
        relevance = np.maximum.reduce([config.noise_factor * noise_floor, config.min_effect_fraction * spread,
                                       np.full(n, resolution)])
        unexplained = np.maximum.reduce([config.noise_factor * noise_floor, config.unexplained_fraction * spread,
                                         np.full(n, resolution)])
        return cls(z_two_sided(config.alpha / num_tests), config.min_heldout_gain, relevance, unexplained)


def z_two_sided(p: float) -> float:
    """z with P(|N(0, 1)| > z) = p."""
    # scipy.special, imported here: lighter than scipy.stats and kept out of `import pe_drake`.
    from scipy.special import ndtri

    return float(-ndtri(p / 2))
