"""A trajectory that stops: a Fourier trajectory re-timed so that every joint holds still at
regular intervals (the test data of the holding-torque diagnosis, tests/test_holding.py)."""

from __future__ import annotations

import dataclasses

import numpy as np


def _blend(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Quintic smoothstep 0 → 1 on u in [0, 1] and its derivative (C² at both ends)."""
    u = np.clip(u, 0.0, 1.0)
    return u**3 * (10 - 15 * u + 6 * u**2), 30 * u**2 * (1 - u) ** 2


@dataclasses.dataclass(frozen=True)
class HeldTrajectory:
    """``base`` along the phase s(t) whose rate ṡ ramps to 0, holds ``hold`` s, ramps back to
    1, every ``every`` s (so q(t) = q_base(s(t)) stops; v = q'·ṡ, v̇ = q''·ṡ² + q'·s̈).

    Attributes:
        base: a trajectory with ``evaluate(t) -> (q, v, vd)`` and ``num_joints``.
        every: time between the starts of two stops [s].
        hold: time at rest [s].
        ramp: time of each ramp of ṡ [s].
    """

    base: object
    every: float = 3.0
    hold: float = 1.0
    ramp: float = 0.3

    @property
    def num_joints(self) -> int:
        return self.base.num_joints

    @property
    def period(self) -> float:
        return self.base.period

    def _rate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """ṡ and s̈ at times t."""
        tau = np.mod(t, self.every) - (self.every - self.hold - 2 * self.ramp)  # time into the stop
        down, d_down = _blend(tau / self.ramp)
        up, d_up = _blend((tau - self.ramp - self.hold) / self.ramp)
        return 1.0 - down + up, (-d_down + d_up) / self.ramp

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        t = np.asarray(t, float)
        fine = np.linspace(0.0, max(float(t.max()), 0.0), max(int(np.ceil(t.max() * 2000)), 2) + 1)
        rate_fine, _ = self._rate(fine)
        s_fine = np.concatenate([[0.0], np.cumsum(0.5 * (rate_fine[1:] + rate_fine[:-1]) * np.diff(fine))])
        s = np.interp(t, fine, s_fine)
        sd, sdd = self._rate(t)
        q, v, vd = self.base.evaluate(s)
        return q, v * sd[:, None], vd * (sd**2)[:, None] + v * sdd[:, None]
